"""Standing push recovery within the leg's reach (issue 38): a recovering foot lands at most
``recovery_max_split`` from the stance sole's centre (the recovery box's corners are ~0.9 m away,
beyond a G1 leg: a diagonal push's split sank and the robot fell)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion.footsteps import Footstep
from giwbc.locomotion.lipm import natural_frequency
from giwbc.locomotion.push_scoring import SETTLE_AFTER_PUSH_S, judge_push
from giwbc.locomotion.simulation import Push, simulate_walk
from giwbc.locomotion.step_adapter import StepAdapter, StepFrame
from giwbc.locomotion.walker import WalkerConfig


def test_a_moved_landing_keeps_the_time_and_the_predicted_dcm():
    """StepAdjustment.landing_moved: the landing given in the (turned) stance frame, in the world; the
    touch-down time and the DCM predicted at it unchanged; the offset is from the new landing."""
    stance = Footstep("right", np.array([0.3, -0.2]), 0.5)
    frame = StepFrame(stance, np.array([0.5, 0.1]), np.array([0.0, -0.05]))
    adjustment = StepAdapter(natural_frequency(0.68)).adapt_in(frame, stance.position, np.array([0.6, 0.3]), 0.3, ((-0.45, 0.5), (0.17, 0.75)), (0.05, 0.5))
    moved = adjustment.landing_moved(0.2, 0.4)
    c, s = math.cos(0.5), math.sin(0.5)
    assert moved.position == pytest.approx([0.3 + 0.2 * c - 0.4 * s, -0.2 + 0.2 * s + 0.4 * c], abs=1e-12)
    assert moved.remaining_time == adjustment.remaining_time
    assert moved.dcm_at_touchdown == pytest.approx(adjustment.dcm_at_touchdown, abs=1e-12)
    assert moved.offset == pytest.approx(moved.dcm_at_touchdown - moved.position, abs=1e-12)


@pytest.mark.parametrize("value", [0.1, -1.0, math.nan])
def test_bad_recovery_split_is_refused(value):
    with pytest.raises(ValueError, match="recovery_max_split"):
        WalkerConfig(recovery_max_split=value)


def _recovery(g1, config: WalkerConfig):
    """Standing (seed 700, the impulse grid's push time), 35 N s (350 N x 0.1 s) forward-left: the run and
    each recovery touch-down's distance from the other (stance) foot."""
    start = float(np.random.default_rng(700).uniform(1.2, 1.6))  # benchmarks/locomotion.py's draw
    push = Push(start, 350.0, math.pi / 4, 0.1)
    splits: list[float] = []
    count = {"steps": 0}

    def watch(robot, walker) -> None:
        if walker.state.steps != count["steps"]:
            count["steps"] = walker.state.steps
            feet = walker.feet  # (the foot just landed, measured at its touch-down)
            splits.append(float(np.linalg.norm(feet["left"].position - feet["right"].position)))

    run = simulate_walk(g1, (0.0, 0.0, 0.0), start + 0.1 + SETTLE_AFTER_PUSH_S + 0.005, pushes=(push,), command_start=None, seed=700,
                        config=config, observe=watch)
    return run, push, splits


def test_a_diagonal_push_is_caught_within_the_legs_reach(g1):
    """Without the limit the left foot lands at the recovery box's corner, 0.94 m from the right foot
    (on, 0.48 m, across 0.84 m); the pelvis rolls 14 deg, the CoM sinks from 0.68 to 0.45 m and the
    robot falls 0.6 s after the push. With it (0.75 m) the foot lands within reach and the robot is
    up 3 s after the push, upright (judge_push, the standing protocol's 0.35 rad)."""
    results = {}
    for name, config in (("off", WalkerConfig(recovery_max_split=math.inf)), ("on", WalkerConfig())):
        run, push, splits = _recovery(g1, config)
        judged = judge_push(fell=run.fell, fall_time=run.fall_time, end_time=run.seconds, push_end=push.start + push.duration,
                            final_tilt=run.final_tilt, upright_tilt=0.35)
        results[name] = (run, judged, splits)
    run, judged, splits = results["off"]
    assert not judged.success and judged.fall_after_push is not None and judged.fall_after_push < 1.5
    assert splits and splits[0] > 0.85
    run, judged, splits = results["on"]
    assert judged.success and run.recovery_steps >= 1 and run.wbc_failures == 0
    assert max(splits) < 0.75 + 0.05  # the soles' centres (the landing within 0.75 m; the stance foot may turn a little)
