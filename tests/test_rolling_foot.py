"""A stance foot rolled onto a rim has the CoP the walker asks held on its raised side, and a QP
whose joint-limit bounds leave no solution (an ankle turning fast) is solved again without them."""

import math

import numpy as np
import pytest

from giwbc.control.balance import BalanceConfig, BalanceController
from giwbc.locomotion.rolling_foot import cop_on_raised_side, lateral_rise
from giwbc.locomotion.walker_config import walker_config
from giwbc.robot.description import load


def _rolled(angle: float) -> np.ndarray:
    """A sole rotated ``angle`` rad about its long (x) axis: > 0 lifts its +y edge."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def test_lateral_rise_says_which_edge_went_down() -> None:
    assert lateral_rise(np.eye(3)) == 0.0
    assert lateral_rise(_rolled(math.radians(10))) == pytest.approx(math.sin(math.radians(10)))
    assert lateral_rise(_rolled(-math.radians(10))) < 0.0


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5])
def test_rolled_foot_cop_moves_to_the_raised_side_along_the_foot_kept(yaw: float) -> None:
    position = np.array([0.3, -0.1])
    c, s = math.cos(yaw), math.sin(yaw)
    along, across = np.array([c, s]), np.array([-s, c])
    asked = position + 0.02 * along - 0.025 * across  # at the -y rim, 2 cm forward
    # rolled 10 deg onto its -y edge (+y raised): the CoP comes to the centre line plus the margin
    cop, moved = cop_on_raised_side(asked, position, yaw, lateral_rise(_rolled(math.radians(10))), math.radians(6), 0.004)
    assert moved
    assert float((cop - position) @ across) == pytest.approx(0.004)
    assert float((cop - position) @ along) == pytest.approx(0.02)
    # rolled onto the other edge: the CoP asked there (-y) is already on the raised side, kept
    cop, moved = cop_on_raised_side(asked, position, yaw, lateral_rise(_rolled(-math.radians(10))), math.radians(6), 0.004)
    assert not moved and np.array_equal(cop, asked)
    # a foot within the tilt (a flat sole's noise) is asked what the DCM controller asked
    cop, moved = cop_on_raised_side(asked, position, yaw, lateral_rise(_rolled(math.radians(4))), math.radians(6), 0.004)
    assert not moved and np.array_equal(cop, asked)


def test_any_floor_watches_rolling_feet_and_the_default_does_not() -> None:
    assert walker_config().roll_cop_tilt == 0.0 and not walker_config().relax_joint_limits
    preset = walker_config("any_floor")
    assert preset.roll_cop_tilt > 0.0 and preset.relax_joint_limits


def test_qp_without_a_solution_under_its_joint_limit_bounds_is_solved_without_them() -> None:
    """A standing G1 whose left ankle roll turns at 20 rad/s (a foot rolling over on a point): the
    bounds would stop the joint within their horizon, which the flat stance foot's contact rows
    and the torque limits do not allow; without them the tick solves, within the torque limits."""
    description = load("g1")
    outcomes = {}
    for relax in (False, True):
        balance = BalanceController(description, BalanceConfig(joint_limits=True, joint_limit_margin=0.04, min_normal_force=5.0))
        q = description.default_configuration()
        balance.reset(q)
        wbc = balance.wbc
        wbc.relax_joint_limits = relax
        v = np.zeros(wbc.model.nv)
        assert wbc.update(q, v, 0.0).ok
        v[wbc.model.joints[wbc.model.getJointId("left_ankle_roll_joint")].idx_v] = 20.0
        result = wbc.update(q, v, 0.002)
        outcomes[relax] = (result.ok, wbc.relaxed_solves)
        if relax:
            assert np.all(np.abs(result.tau) <= wbc.torque_limits + 1e-9)
            # the next still tick has its bounds again and needs no relaxing
            assert wbc.update(q, np.zeros(wbc.model.nv), 0.004).ok and wbc.relaxed_solves == 1
    assert outcomes == {False: (False, 0), True: (True, 1)}
