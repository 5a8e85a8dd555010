"""The WBC's contact set: the one lever rule, the weight shares it gives the force regularisation,
and the gradient the QP gets from them (statics: the shares support the weight at the point)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from giwbc.control import Kinodynamics, make_balance_controller
from giwbc.control.contact_set import Lever


def test_the_lever_rule_is_the_static_split_of_a_weight_between_two_points():
    p1, p2 = (0.3, 0.1), (-0.1, -0.2)
    lever = Lever.between(p1, p2)
    assert lever.share(*p1) == pytest.approx(1.0) and lever.share(*p2) == pytest.approx(0.0)
    # A point on the segment: the shares balance the moment about it (α (p1 − s) + (1 − α)(p2 − s) = 0).
    s = 0.25 * np.array(p1) + 0.75 * np.array(p2)
    alpha = lever.share(*s)
    assert alpha == pytest.approx(0.25)
    np.testing.assert_allclose(alpha * (np.array(p1) - s) + (1 - alpha) * (np.array(p2) - s), 0.0, atol=1e-12)
    # Off the segment: the projection on it; beyond the ends: all on the nearer point.
    normal = np.array([0.3, -0.4])  # ⟂ (p1 − p2) = (0.4, 0.3)
    assert lever.share(*(s + normal)) == pytest.approx(0.25)
    assert lever.share(*(np.array(p1) + 2.0 * (np.array(p1) - np.array(p2)))) == 1.0
    assert lever.share(*(np.array(p2) - (np.array(p1) - np.array(p2)))) == 0.0
    assert Lever.between(p1, p1) is None  # coincident points: no split


def _standing(g1, support: np.ndarray | None):
    controller = make_balance_controller(g1)
    q, v = g1.default_configuration(), np.zeros(g1.build_pinocchio().nv)
    controller.update(q, v, 0.0)
    if support is not None:
        controller.wbc.force_regularization.set_support_point(support)
    controller.wbc.update(q, v, 0.002)
    return controller


@pytest.mark.parametrize("fraction", [0.5, 0.8, 1.3])
def test_shares_put_the_weight_where_the_support_point_is(g1, fraction):
    """Two fully made feet and a support point a fraction of the way from the right foot to the
    left: the left foot's share is that fraction (clipped to [0, 1]), and the QP's force gradient
    asks each foot for its share of the weight."""
    controller = _standing(g1, None)
    wbc = controller.wbc
    contacts = wbc.contact_set
    left, right = (contacts.slot(c.name) for c in controller.contacts)
    p_left, p_right = np.array(contacts.contact_xy(left)), np.array(contacts.contact_xy(right))
    point = p_right + fraction * (p_left - p_right)
    controller = _standing(g1, np.array([*point, 0.0]))
    wbc = controller.wbc
    shares = wbc.contact_set.shares(wbc.force_regularization)
    expected = min(max(fraction, 0.0), 1.0)
    assert shares == pytest.approx([expected, 1.0 - expected])
    weight = wbc.contact_set.weight_force
    assert weight == pytest.approx(g1.total_mass * 9.81, rel=1e-6)
    reg = wbc.force_regularization
    g = wbc.problem.g
    for slot, share in zip(wbc.contact_set.slot_list, shares):
        normal = slot.columns.start + 2  # f_z of the 6D wrench
        assert g[normal] == pytest.approx(-reg.weight * weight * share)


def test_a_contact_ramping_out_shares_by_activation(g1):
    """While one foot's force ramps out, its share is the lever rule's scaled by its activation."""
    controller = make_balance_controller(g1)
    wbc = controller.wbc
    q, v = g1.default_configuration(), np.zeros(wbc.nv)
    wbc.update(q, v, 0.0)
    left, right = (c.name for c in controller.contacts)
    wbc.remove_contact(right, ramp_time=0.1)
    for i in range(1, 27):
        wbc.update(q, v, i * 0.002)
    activation = wbc.contact_activation(right)
    assert activation == pytest.approx(1.0 - 0.05 / 0.1)  # half-way down (the ramp started at 0.002 s)
    contacts = wbc.contact_set
    reg = wbc.force_regularization
    shares = contacts.shares(reg)
    if reg.support_point is None:  # by activation
        expected = [1.0 / (1.0 + activation), activation / (1.0 + activation)]
    else:  # the lever rule, each side scaled by its activation
        lever = Lever.between(contacts.contact_xy(contacts.slot(left)), contacts.contact_xy(contacts.slot(right)))
        alpha = lever.share(*reg.support_point[:2])
        a1, a2 = alpha, (1.0 - alpha) * activation
        expected = [a1 / (a1 + a2), a2 / (a1 + a2)]
    assert sum(shares) == pytest.approx(1.0)
    assert shares == pytest.approx(expected)
    assert shares[1] < 0.5  # the foot being lifted carries less than its static share


def test_a_contact_re_made_after_its_offset_moved_uses_the_new_offset(g1):
    """Re-making a known contact skips binding it again only while its link and offset are the
    ones it was bound with: a moved sole centre is where the re-made contact's frame is."""
    controller = _standing(g1, None)
    wbc = controller.wbc
    contact = wbc.contacts[0]
    before = pin.SE3(contact.placement)
    wbc.remove_contact(contact.name)
    wbc.add_contact(contact)  # the same contact again: the same frame
    assert contact.placement.isApprox(before, 0.0)
    wbc.remove_contact(contact.name)
    contact.offset = contact.offset * pin.SE3(np.eye(3), np.array([0.02, 0.0, 0.0]))
    wbc.add_contact(contact)
    moved = before * pin.SE3(np.eye(3), np.array([0.02, 0.0, 0.0]))
    np.testing.assert_allclose(contact.placement.translation, moved.translation, atol=1e-15)
    assert not np.allclose(contact.placement.translation, before.translation)


def test_a_contact_is_bound_only_to_the_model_link_and_offset_it_was_bound_with(g1):
    """``Contact.is_bound``, which lets the controller skip binding a re-made contact, is False for
    another model's kinodynamics, another link or another offset; a contact re-made on the other
    foot's link is bound to that link."""
    controller = _standing(g1, None)
    wbc = controller.wbc
    contact, other = wbc.contacts[0], wbc.contacts[1]
    assert contact.link != other.link
    assert contact.is_bound(wbc.kin)
    assert not contact.is_bound(Kinodynamics(g1.build_pinocchio(), n_base=wbc.n_base))
    link = contact.link
    contact.link = other.link
    assert not contact.is_bound(wbc.kin)
    contact.link = link
    offset = contact.offset
    contact.offset = offset * pin.SE3(np.eye(3), np.array([0.0, 0.01, 0.0]))
    assert not contact.is_bound(wbc.kin)
    contact.offset = offset
    assert contact.is_bound(wbc.kin)
    wbc.remove_contact(contact.name)
    contact.link = other.link
    wbc.add_contact(contact)
    assert contact.joint_id == other.joint_id
    assert contact.placement.isApprox(other.placement * other.offset.inverse() * contact.offset, 1e-12)


def test_a_contact_made_at_zero_force_is_declared_fixed_until_its_ramp_opens_it(g1):
    """Single support (the right foot broken: its 6 wrench variables and 6 motion rows pinned,
    declared fixed, the same declaration tick after tick), then the right foot made again with
    a ramp: at its first tick its normal force is capped at 0, so its forces are declared fixed
    with its friction rows (no equality row: its motion rows hold the foot); from the next tick
    the ramp has opened the cone and nothing is declared."""
    controller = make_balance_controller(g1)
    wbc = controller.wbc
    q, v = g1.default_configuration(), np.zeros(wbc.nv)
    wbc.update(q, v, 0.0)
    right = controller.contacts[1]
    wbc.remove_contact(right.name)
    wbc.update(q, v, 0.002)
    wbc.update(q, v, 0.004)
    slot = wbc.contact_set.slot(right.name)
    fixed = wbc.problem.fixed
    assert fixed is not None and len(fixed) == 2
    np.testing.assert_array_equal(fixed[0], np.arange(slot.columns.start, slot.columns.stop))
    np.testing.assert_array_equal(fixed[1], np.arange(slot.motion_rows.start, slot.motion_rows.stop))
    wbc.update(q, v, 0.006)
    assert wbc.problem.fixed is fixed  # unchanged: not replaced (a new tuple is a change to the QP guess)
    wbc.add_contact(right, ramp_time=0.1)
    wbc.update(q, v, 0.008)
    assert slot.engaged and slot.activation == 0.0 and not slot.pinned
    fixed = wbc.problem.fixed
    assert fixed is not None and len(fixed) == 3
    np.testing.assert_array_equal(fixed[0], np.arange(slot.columns.start, slot.columns.stop))
    assert len(fixed[1]) == 0
    np.testing.assert_array_equal(fixed[2], np.arange(slot.friction_rows.start, slot.friction_rows.stop))
    wbc.update(q, v, 0.010)
    assert 0.0 < slot.activation < 1.0 and wbc.problem.fixed is None
