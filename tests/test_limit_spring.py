"""The WBC's joint-limit spring: a joint inside the zone before its position limit gets a torque
back out of it on top of the QP's (a foot rolling on its rim turns with its ankle roll joint,
which the QP, holding the foot flat, cannot stop); a joint outside the zone gets nothing."""

from __future__ import annotations

import numpy as np
import pytest

from giwbc.control.balance import BalanceConfig, BalanceController
from giwbc.robot.description import load

ZONE, KP, KD = 0.05, 600.0, 10.0


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def _torques(g1, q, v, spring: bool) -> np.ndarray:
    controller = BalanceController(g1, BalanceConfig(limit_spring=(ZONE, KP, KD) if spring else None))
    controller.reset(g1.default_configuration())
    return controller.update(q, v, 0.0).tau


def test_a_joint_in_the_zone_is_pushed_back_and_damped_only_moving_deeper(g1):
    joint = g1.joint_names.index("left_ankle_roll_joint")
    lower, upper = (limits[joint] for limits in g1.position_limits)
    q = g1.default_configuration()
    v = np.zeros(g1.pinocchio_model.nv)
    depth = 0.02
    q[7 + joint] = upper - ZONE + depth  # 20 mrad into the upper zone
    v[6 + joint] = 0.5  # moving further in
    added = _torques(g1, q, v, True) - _torques(g1, q, v, False)
    assert added[joint] == pytest.approx(-KP * depth - KD * 0.5, abs=1e-6)  # out of the zone: negative, N m
    others = np.delete(added, joint)
    assert np.abs(others).max() < 1e-9  # no other joint is near a limit
    v[6 + joint] = -0.5  # already moving back out: the spring alone, no damping against it
    added = _torques(g1, q, v, True) - _torques(g1, q, v, False)
    assert added[joint] == pytest.approx(-KP * depth, abs=1e-6)
    q[7 + joint] = lower + ZONE - depth  # the lower zone: pushed up
    v[6 + joint] = -0.5
    added = _torques(g1, q, v, True) - _torques(g1, q, v, False)
    assert added[joint] == pytest.approx(KP * depth + KD * 0.5, abs=1e-6)


def test_joints_outside_the_zone_get_exactly_the_qp_torque(g1):
    """Standing at the default pose every joint is far from its limits: bit-identical torques."""
    q = g1.default_configuration()
    v = np.zeros(g1.pinocchio_model.nv)
    assert np.array_equal(_torques(g1, q, v, True), _torques(g1, q, v, False))


def test_bad_spring_parameters_are_refused(g1):
    with pytest.raises(ValueError, match="limit spring"):
        BalanceController(g1, BalanceConfig(limit_spring=(0.0, KP, KD)))
    with pytest.raises(ValueError, match="limit spring"):
        BalanceController(g1, BalanceConfig(limit_spring=(ZONE, -1.0, KD)))
