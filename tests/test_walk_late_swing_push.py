"""Pushes late in a swing (issue 38, WalkerConfig.late_swing_push): the walking-push check runs to
the touch-down, and a walking recovery's swing past its planned touch-down lands once its sole is
down. Before, a push in a swing's last 0.03 s was seen only at the touch-down, after the late wait."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion.push_scoring import SETTLE_AFTER_PUSH_S, judge_push
from giwbc.locomotion.simulation import Push, simulate_walk
from giwbc.locomotion.walker import Phase, WalkerConfig

# Stepping in place, seed 700: the right foot swings, its planned touch-down at 3.300 s (the unpushed
# run's); 30 N s (300 N x 0.1 s) straight back at 3.1984 s (phase 0.4 of the gait-phase protocol).
IN_PLACE_PUSH = Push(3.1984, 300.0, 0.00624 + math.pi, 0.1)
UNPUSHED_TOUCHDOWN = 3.300


def _first_touchdown(g1, config: WalkerConfig) -> tuple[float, float | None]:
    """(time of the first touch-down after the push, time a walking recovery began while the foot still swung or None)."""
    seen: dict = {"steps": None, "touchdown": math.nan, "recovery_in_swing": None}

    def watch(robot, walker) -> None:
        t = robot.time()
        steps = walker.state.steps
        if seen["steps"] is not None and steps != seen["steps"] and t > IN_PLACE_PUSH.start and math.isnan(seen["touchdown"]):
            seen["touchdown"] = t
        seen["steps"] = steps
        if t > IN_PLACE_PUSH.start and math.isnan(seen["touchdown"]) and walker._recovering and walker.phase is Phase.SINGLE:
            seen["recovery_in_swing"] = seen["recovery_in_swing"] or t

    simulate_walk(g1, (0.0, 0.0, 0.0), 3.40, pushes=(IN_PLACE_PUSH,), step_in_place=True, seed=700, config=config, observe=watch)
    return seen["touchdown"], seen["recovery_in_swing"]


def test_a_push_in_the_last_moments_of_a_swing_is_caught_before_the_touch_down(g1):
    """On: the recovery begins while the right foot still swings and the foot lands sooner than the
    unpushed plan (the robot tips back: the sole down, not yet loaded). Off: nothing until the
    touch-down, which waits past the plan for the load (the late wait) with the DCM running back."""
    on_touchdown, on_recovery = _first_touchdown(g1, WalkerConfig(late_swing_push=True))
    off_touchdown, off_recovery = _first_touchdown(g1, WalkerConfig(late_swing_push=False))
    assert on_recovery is not None and IN_PLACE_PUSH.start < on_recovery < on_touchdown
    assert off_recovery is None
    assert on_touchdown < UNPUSHED_TOUCHDOWN - 0.02 < UNPUSHED_TOUCHDOWN + 0.01 < off_touchdown
    assert off_touchdown - on_touchdown > 0.05


@pytest.mark.slow
def test_late_swing_push_leaves_unpushed_walking_and_standing_recovery_alone(g1):
    """Bit for bit the same on and off: an unpushed walk at 0.5 m/s (its DCM error stays under
    walking_recovery_error) and a standing recovery (not walking)."""
    off = WalkerConfig(late_swing_push=False)
    a = simulate_walk(g1, (0.5, 0.0, 0.0), 2.5, seed=5, config=off)
    b = simulate_walk(g1, (0.5, 0.0, 0.0), 2.5, seed=5, config=WalkerConfig(late_swing_push=True))
    assert b.recovery_steps == 0 and a.steps == b.steps > 2 and np.array_equal(a.distance, b.distance)
    push = (Push(1.3, 100.0, math.pi / 2),)
    a = simulate_walk(g1, (0.0, 0.0, 0.0), 2.2, pushes=push, command_start=None, seed=5, config=off)
    b = simulate_walk(g1, (0.0, 0.0, 0.0), 2.2, pushes=push, command_start=None, seed=5, config=WalkerConfig(late_swing_push=True))
    assert a.recovery_steps >= 1 and a.recovery_steps == b.recovery_steps and np.array_equal(a.distance, b.distance)


@pytest.mark.slow
def test_a_late_swing_push_toward_the_swinging_foot_is_recovered_while_walking(g1):
    """Walking 0.5 m/s (seed 700), 30 N s back-right (5 pi / 4 from the heading) at 3.0316 s, the right
    foot 0.1 s before its touch-down: off, the foot landed short with the DCM outward of it, the left
    foot came down beside it and the right one's next step out was too far (the robot fell ~0.5 s
    after the push); on, the recovery starts in the swing and the robot is up 3 s after the push."""
    push = Push(3.0316, 300.0, 0.01608 + 1.25 * math.pi, 0.1)
    end = push.start + push.duration + SETTLE_AFTER_PUSH_S + 0.005
    runs = [simulate_walk(g1, (0.5, 0.0, 0.0), end, pushes=(push,), seed=700, config=config)
            for config in (WalkerConfig(late_swing_push=False), WalkerConfig(late_swing_push=True))]
    off, on = (judge_push(fell=r.fell, fall_time=r.fall_time, end_time=r.seconds, push_end=push.start + push.duration) for r in runs)
    assert not off.success and off.fall_after_push is not None and off.fall_after_push < 2.0
    assert on.success and runs[1].recovery_steps >= 1
