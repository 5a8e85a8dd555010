"""The limbs' yaw momentum task (giwbc.control.yaw_momentum, BalanceConfig.limb_yaw_momentum_weight,
WalkerConfig.yaw_momentum_weight): a swinging leg's yaw momentum taken by the trunk and arms instead
of a yaw moment on the stance foot."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from giwbc.control.balance import BalanceConfig, BalanceController
from giwbc.control.kinodynamics import Kinodynamics
from giwbc.control.yaw_momentum import LimbYawMomentumTask
from giwbc.locomotion.simulation import simulate_walk
from giwbc.locomotion.walker import Phase, WalkingController
from giwbc.locomotion.walker_config import WalkerConfig, walker_config
from giwbc.robot import load


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def test_the_whole_robot_turning_has_no_limb_yaw_momentum_a_swinging_leg_has(g1) -> None:
    """Rigid rotation of the whole robot (base yaw rate only) carries yaw momentum but none of it is
    the limbs'; a hip pitching forward on one side (a leg swinging at the hip's lateral offset) makes
    yaw momentum of the limbs, of the sign r x p gives (left leg forward: +y cross +x = -z)."""
    model = g1.pinocchio_model
    kin = Kinodynamics(model)
    task = LimbYawMomentumTask()
    task.bind(kin)
    q = g1.default_configuration()
    v = np.zeros(model.nv)
    v[5] = 1.0
    kin.update(q, v)
    assert abs(kin.centroidal_momentum[5]) > 0.5  # the robot's own yaw inertia, kg m^2 x 1 rad/s
    assert abs(task.momentum(kin)) < 1e-9
    rows, error, drift = np.zeros((1, model.nv)), np.zeros(1), np.zeros(1)
    task.write(kin, rows, error, drift)
    assert np.all(rows[0, :6] == 0.0) and error[0] == 0.0
    np.testing.assert_allclose(rows[0, 6:], kin.centroidal_map[5, 6:])
    v = np.zeros(model.nv)
    v[model.joints[model.getJointId("left_hip_pitch_joint")].idx_v] = -2.0  # left thigh swings forward
    kin.update(q, v)
    assert task.momentum(kin) < -0.02
    assert task.momentum(kin) == pytest.approx(kin.centroidal_momentum[5], rel=1e-9, abs=1e-12)  # the base still


def test_the_options_put_the_task_in_the_wbc(g1) -> None:
    walker = WalkingController(g1, WalkerConfig(yaw_momentum_weight=3.0))
    task = walker.balance.limb_yaw_task
    assert task is not None and task.weight[0] == 3.0 and any(t is task for t in walker.wbc.tasks)
    assert WalkingController(g1).balance.limb_yaw_task is None
    assert BalanceController(g1, BalanceConfig(limb_yaw_momentum_weight=1.0, limb_yaw_momentum_kd=5.0)).limb_yaw_task.kd[0] == 5.0
    assert walker_config("any_floor").yaw_momentum_weight == 0.3  # (3 ended the walks on the estimate: walker_config.py)
    with pytest.raises(ValueError, match="yaw_momentum_weight"):
        WalkerConfig(yaw_momentum_weight=-1.0)


def _stance_yaw_moments(description, config: WalkerConfig) -> np.ndarray:
    """The planned yaw moment (N m, contact frame) on the stance foot at every single-support tick of a
    short walk at 0.3 m/s on the nominal plant."""
    moments: list[float] = []

    def observe(robot, controller) -> None:
        result = controller.last_result
        if result is None or controller.state.phase is not Phase.SINGLE:
            return
        name = controller.contacts[controller.state.stance].name
        if name in result.contact_wrenches:
            moments.append(float(result.contact_wrenches[name][5]))

    run = simulate_walk(description, (0.3, 0.0, 0.0), 2.6, config=config, seed=20000, observe=observe)
    assert not run.fell and run.steps >= 3
    return np.abs(np.array(moments))


def test_a_swinging_leg_asks_the_stance_foot_for_less_yaw_moment(g1) -> None:
    """Walking 0.3 m/s (the first steps, nominal plant): without the task the QP plans a yaw moment
    on the stance foot of 4-5 N m on average, over 8 N m at one single-support tick in ten; with it
    (weight 3; the any_floor preset has 0.3) the trunk and arms take the swing leg's yaw momentum and
    both at least halve (measured: mean 5.5 -> 2.5 N m, 90th percentile 10.0 -> 4.8 N m)."""
    without = _stance_yaw_moments(g1, walker_config({"yaw_momentum_weight": 0.0}, walker_config("any_floor")))
    with_task = _stance_yaw_moments(g1, walker_config({"yaw_momentum_weight": 3.0}, walker_config("any_floor")))
    assert without.mean() > 4.0 and np.percentile(without, 90) > 8.0, (without.mean(), np.percentile(without, 90))
    assert with_task.mean() < 0.5 * without.mean(), (with_task.mean(), without.mean())
    assert np.percentile(with_task, 90) < 0.5 * np.percentile(without, 90)
