"""A floor that does not hold yaw (issue 36): the stance sole's turn within one single support
(giwbc.locomotion.rolling_foot.YawSlipWatch) raises the limbs' yaw momentum task's weight
(WalkerConfig.yaw_slip_weight; the any_floor preset) on the soft floor, never on the nominal plant."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion.rolling_foot import YawSlipWatch, heading
from giwbc.locomotion.simulation import simulate_walk
from giwbc.locomotion.walker import Phase, WalkingController
from giwbc.locomotion.walker_config import ANY_FLOOR_OPTIONS, WalkerConfig, walker_config
from giwbc.robot import load


def _yaw(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_a_turn_past_the_angle_within_one_support_is_a_slip_held_for_the_hold_time() -> None:
    """A sole turning 0 -> 12 deg in 0.1 s (across the +-pi seam: headings near 180 deg) passes a 10 deg
    watch when it passes 10 deg; a foot rocking +-5 deg does not; a new support starts from its own
    heading (the 12 deg already turned is not carried); the slip reads True for ``hold`` s after."""
    watch = YawSlipWatch(math.radians(10.0), hold=1.0)
    start = math.radians(175.0)
    times = np.arange(51) * 0.002
    seen = [watch.update(t, ("left", 0.0), heading(_yaw(start + math.radians(12.0) * t / 0.1))) for t in times]
    first = times[seen.index(True)]
    assert 0.082 <= first <= 0.086  # 10 / 12 of the way
    assert watch.slips == 1 and math.degrees(watch.turned) == pytest.approx(12.0, abs=1e-6)
    assert watch.update(0.5, None, None)  # double support: the slip is still held ...
    assert watch.update(0.12, ("right", 0.5), 0.0) and watch.update(1.10, ("right", 0.5), 0.0)
    assert not watch.update(1.11, ("right", 0.5), 0.0)  # ... for 1 s after the last turn past 10 deg
    rocking = YawSlipWatch(math.radians(10.0), hold=1.0)
    assert not any(rocking.update(t, ("left", 0.0), math.radians(5.0) * math.sin(40.0 * t)) for t in times)
    assert rocking.slips == 0
    with pytest.raises(ValueError, match="angle"):
        YawSlipWatch(0.0, 1.0)
    with pytest.raises(ValueError, match="yaw_slip_weight"):
        WalkerConfig(yaw_slip_weight=math.nan)


def test_the_soft_floor_turns_a_stance_foot_and_raises_the_weight_the_nominal_plant_does_not() -> None:
    """any_floor walking 0.5 m/s for 3 s: on the soft floor (MuJoCo's soft contact creeps under the yaw
    moment of a lift-off) a stance sole turns past 10 deg within a single support and the task's weight
    goes to yaw_slip_weight; on the nominal plant (box feet, stiff contact) no stance sole turns more
    than 3 deg and the weight stays at yaw_momentum_weight throughout."""
    g1 = load("g1")
    config = walker_config("any_floor")
    low, high = ANY_FLOOR_OPTIONS["yaw_momentum_weight"], ANY_FLOOR_OPTIONS["yaw_slip_weight"]
    for plant, slips in (("soft_floor", True), (None, False)):
        weights: set[float] = set()
        turned = [0.0]

        def observe(robot, controller) -> None:
            weights.add(float(controller.balance.limb_yaw_task.weight[0]))
            if controller.phase is Phase.SINGLE:
                turned[0] = max(turned[0], controller._yaw_slip.turned)

        run = simulate_walk(g1, (0.5, 0.0, 0.0), 3.0, command_start=0.5, seed=20001, config=config, plant=plant, observe=observe)
        assert not run.fell
        if slips:
            assert math.degrees(turned[0]) > ANY_FLOOR_OPTIONS["yaw_slip_angle"] and weights == {low, high}
        else:
            assert math.degrees(turned[0]) < 3.0 and weights == {low}
    # Without the task (the preset with yaw_momentum_weight 0) there is nothing to schedule.
    assert WalkingController(g1, walker_config({"yaw_momentum_weight": 0.0}, config))._yaw_slip is None
