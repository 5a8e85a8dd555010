"""The feet's yaw moment bound (BalanceConfig.torsion / WalkerConfig.torsion): |tau_z| <= torsion * f_z
on every support of a sole, for floors that turn a loaded foot well inside their sliding friction."""

from __future__ import annotations

import numpy as np
import pytest

from giwbc.control.balance import BalanceConfig, BalanceController
from giwbc.control.contacts import foot_contacts, wrench_cone_matrix
from giwbc.control.sole import SoleSupport
from giwbc.locomotion.walker import WalkingController
from giwbc.locomotion.walker_config import WalkerConfig
from giwbc.robot import load


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def _inside(support: SoleSupport, mode: int, wrench: np.ndarray) -> bool:
    return bool((support.matrices[mode, : support.counts[mode]] @ wrench).max() <= 1e-12)


def test_every_support_keeps_its_yaw_moment_within_the_bound() -> None:
    corners = np.array([[0.07, 0.025], [-0.07, 0.025], [-0.07, -0.025], [0.07, -0.025]])
    free = SoleSupport(corners, 0.8, full_rows=wrench_cone_matrix(0.07, 0.025, 0.8))
    bounded = SoleSupport(corners, 0.8, full_rows=wrench_cone_matrix(0.07, 0.025, 0.8), torsion=0.01)
    assert bounded.n_rows == free.n_rows + 2 and bounded.counts == [n + 2 for n in free.counts]
    for mode, support in enumerate(bounded.modes):
        centre = support.polygon.mean(axis=0)  # a CoP inside this support, 100 N
        wrench = np.array([0.0, 0.0, 100.0, 100.0 * centre[1], -100.0 * centre[0], 0.0])
        assert _inside(bounded, mode, wrench)
        for yaw in (0.5, 0.9, 1.1, -0.5, -0.9, -1.1):  # the bound: 0.01 m x 100 N = 1 N m
            turned = wrench + [0, 0, 0, 0, 0, yaw]
            assert _inside(bounded, mode, turned) == (_inside(free, mode, turned) and abs(yaw) < 1.0), (support.kind, yaw)
    # The whole sole's friction alone allows more: mu (X + Y) f_z = 7.6 N m at 100 N.
    assert _inside(free, 0, np.array([0.0, 0.0, 100.0, 0.0, 0.0, 5.0]))
    assert not _inside(bounded, 0, np.array([0.0, 0.0, 100.0, 0.0, 0.0, 5.0]))


def test_bad_torsion_is_refused(g1) -> None:
    with pytest.raises(ValueError, match="torsion"):
        SoleSupport(np.array([[0.1, 0.0], [0.0, 0.1], [-0.1, -0.1]]), 0.8, torsion=0.0)
    with pytest.raises(ValueError, match="torsion"):
        foot_contacts(g1, "corners", torsion=0.01)
    with pytest.raises(ValueError, match="torsion"):
        WalkerConfig(torsion=float("nan"))


def test_the_qp_turns_the_base_within_the_feets_yaw_moment(g1) -> None:
    """Standing, the base turning at 1 rad/s: the orientation task asks the feet for a yaw moment.
    Unbounded the QP plans more than 0.005 m x f_z on a foot; bounded, never more."""

    def worst_ratio(config: BalanceConfig) -> float:
        controller = BalanceController(g1, config)
        q = g1.default_configuration()
        v = np.zeros(g1.pinocchio_model.nv)
        v[5] = 1.0  # base yaw rate
        controller.reset(q)
        result = controller.update(q, v, 0.0)
        ratios = [abs(w[5]) / w[2] for w in result.contact_wrenches.values()]
        assert min(w[2] for w in result.contact_wrenches.values()) > 50.0
        return max(ratios)

    assert worst_ratio(BalanceConfig()) > 0.005
    assert worst_ratio(BalanceConfig(torsion=0.005)) <= 0.005 * (1.0 + 1e-6)


def test_the_walker_passes_its_torsion_to_the_wbc(g1) -> None:
    walker = WalkingController(g1, WalkerConfig(torsion=0.02))
    assert [c.torsion for c in walker.balance.contacts] == [0.02, 0.02]
    assert [c.torsion for c in WalkingController(g1).balance.contacts] == [None, None]
