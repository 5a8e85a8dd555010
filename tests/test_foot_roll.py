"""Foot-roll detection: a foot that starts to roll is seen within a few ticks and stands on the
edge it rolled onto (its CoP constrained there); flat again, it gets its whole sole back."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from giwbc.control.balance import BalanceConfig, BalanceController
from giwbc.control.sole import RollDetector, SoleSupport
from giwbc.robot.description import load

DT = 0.002


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def test_mode_for_tilt_picks_the_low_edge_or_corner():
    box = SoleSupport(np.array([[0.07, 0.025], [0.07, -0.025], [-0.07, 0.025], [-0.07, -0.025]]), 0.8)
    heights_low = lambda mode: {tuple(box.polygon[i]) for i in box.modes[mode].vertices}
    # sole plane lower on -y (rolled onto its right edge): the two right vertices
    assert heights_low(box.mode_for_tilt(np.array([0.0, 0.03]))) == {(0.07, -0.025), (-0.07, -0.025)}
    assert heights_low(box.mode_for_tilt(np.array([-0.03, 0.0]))) == {(0.07, 0.025), (0.07, -0.025)}  # onto the toe
    corner = box.mode_for_tilt(np.array([0.03, 0.03]))  # diagonal: the back-right corner alone
    assert box.modes[corner].kind == "corner" and heights_low(corner) == {(-0.07, -0.025)}


def test_detector_refuses_bad_thresholds():
    with pytest.raises(ValueError, match="tilt_off"):
        RollDetector(tilt_on=0.01, tilt_off=0.02)


def _rolling_run(g1, rate: float, ticks: int, config: BalanceConfig):
    """Both feet down; the left ankle roll joint turns at ``rate`` rad/s (the foot rolls about x)
    with the base still: returns the controller and the first tick the left foot left FULL."""
    controller = BalanceController(g1, config)
    q = g1.default_configuration()
    v = np.zeros(g1.pinocchio_model.nv)
    controller.reset(q)
    joint = g1.joint_names.index("left_ankle_roll_joint")
    first = None
    left = controller.contacts[0]
    for i in range(ticks):
        angle = rate * DT * i
        qi, vi = q.copy(), v.copy()
        qi[7 + joint] += angle
        vi[6 + joint] = rate
        result = controller.update(qi, vi, DT * i)
        if first is None and left.support_mode != 0:
            first = i
    return controller, first, result


def test_a_rolling_foot_is_detected_within_a_few_ticks(g1):
    config = BalanceConfig(roll_tilt_on=3.0, roll_tilt_off=1.5, roll_lookahead=0.01)
    controller, first, result = _rolling_run(g1, rate=math.radians(60.0), ticks=40, config=config)
    # 3 deg at 60 deg/s is 25 ticks of rolling; with 10 ms look-ahead it is seen ~5 ticks earlier
    assert first is not None and first <= 25
    left, right = controller.contacts
    mode = left.support.modes[left.support_mode]
    assert mode.kind == "edge"
    assert right.support_mode == 0  # the other foot did not move
    # the foot stands on one of its long edges (both vertices on one side of the centreline)
    rotation_low = np.sign(left.support.polygon[list(mode.vertices), 1])
    assert abs(rotation_low.sum()) == 2  # both vertices on one side (a long edge)
    wrench = result.contact_wrenches[left.name]
    cop = np.array([-wrench[4], wrench[3]]) / wrench[2]
    polygon = left.support_polygon()
    assert polygon[:, 1].min() - 1e-6 <= cop[1] <= polygon[:, 1].max() + 1e-6  # the CoP on the rolled edge's strip


def test_a_still_foot_is_never_rolled_and_a_flat_one_comes_back(g1):
    config = BalanceConfig(roll_tilt_on=3.0, roll_tilt_off=1.5, roll_lookahead=0.01)
    controller, first, _ = _rolling_run(g1, rate=0.0, ticks=30, config=config)
    assert first is None
    controller, first, _ = _rolling_run(g1, rate=math.radians(60.0), ticks=40, config=config)
    left = controller.contacts[0]
    assert left.support_mode != 0
    q = g1.default_configuration()
    v = np.zeros(g1.pinocchio_model.nv)
    for i in range(40, 80):  # flat and still again: the whole sole after release_time (50 ms)
        controller.update(q, v, DT * i)
    assert left.support_mode == 0


def test_sole_learning_moves_the_rolled_over_edge_inward(g1):
    """With ``sole_learning_step`` each roll moves the edge the foot rolled over inward, and the other
    edge at the lowest corner by half as much (a foot whose real sole is smaller than the
    description's learns it); the friction rows keep their count."""
    config = BalanceConfig(roll_tilt_on=3.0, roll_tilt_off=1.5, roll_lookahead=0.01, roll_supports=False, sole_learning_step=0.003)
    box = replace(g1, contacts=tuple(replace(contact, sole=()) for contact in g1.contacts))  # learning moves a rectangle's edges
    controller, first, result = _rolling_run(box, rate=math.radians(60.0), ticks=40, config=config)
    left, right = controller.contacts
    assert left.learned_rolls == 1 and right.learned_rolls == 0 and left.support_mode == 0
    before = right.support_polygon()
    after = left.support_polygon()
    assert np.ptp(after[:, 1]) == pytest.approx(np.ptp(before[:, 1]) - 0.003)  # the side it rolled over: in by a step
    assert np.ptp(after[:, 0]) == pytest.approx(np.ptp(before[:, 0]) - 0.5 * 0.003)  # the lowest corner's other edge: half a step
    assert left.n_ineq == right.n_ineq
    wrench = result.contact_wrenches[left.name]
    cop = np.array([-wrench[4], wrench[3]]) / wrench[2]
    assert after[:, 1].min() - 1e-6 <= cop[1] <= after[:, 1].max() + 1e-6
