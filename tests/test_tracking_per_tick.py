"""Per-tick heading-frame velocity tracking (mjlab's ``track_lin_vel_xy``) against hand-computed trajectories."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion.tracking import heading_frame_velocity, per_tick_tracking


def test_a_world_velocity_is_rotated_into_the_heading_frame() -> None:
    # Heading +y (yaw π/2): forward is world +y and left world −x, so world (−0.1, 0.3) is 0.3 forward, 0.1 left.
    v = heading_frame_velocity(np.array([[-0.1, 0.3]]), np.array([math.pi / 2]))
    assert v == pytest.approx(np.array([[0.3, 0.1]]))
    # Heading π: world +x is backward.
    assert heading_frame_velocity(np.array([[0.2, 0.0]]), np.array([math.pi])) == pytest.approx(np.array([[-0.2, 0.0]]))


def test_a_constant_offset_scores_the_same_both_ways() -> None:
    """Heading +y, walking 0.3 forward with a 0.1 lateral drift, on a (0.3, 0, 0.2) command, turning 0.2 rad/s exactly:
    every tick is off by 0.1 m/s, the yaw rate never."""
    n = 50
    tracking = per_tick_tracking(np.tile([-0.1, 0.3], (n, 1)), np.full(n, math.pi / 2), np.full(n, 0.2), np.array([0.3, 0.0, 0.2]))
    assert tracking.ticks == n
    assert tracking.tracking_rms_per_tick_heading_xy == pytest.approx(0.1)
    assert tracking.tracking_mean_abs_per_tick_heading_xy == pytest.approx(0.1)
    assert tracking.yaw_rate_rms_per_tick == pytest.approx(0.0, abs=1e-15)
    assert tracking.yaw_rate_mean_abs_per_tick == pytest.approx(0.0, abs=1e-15)


def test_sway_within_a_step_counts_per_tick() -> None:
    """A lateral sway 0.1 sin(2π t / T) in the heading frame of a robot turning at 0.5 rad/s, forward speed on the
    command: RMS 0.1/√2 and mean absolute 0.2/π (whole periods), though its average over each period is zero.
    The yaw rate alternates 0.5 ± 0.1 and 0.5 ∓ 0.3 around a 0.5 command: RMS √0.05, mean absolute 0.2."""
    t = np.arange(0.0, 4.0, 0.002)  # 500 Hz, 4 whole periods of 1 s
    yaw = 0.3 + 0.5 * t
    forward, lateral = np.full(len(t), 0.4), 0.1 * np.sin(2 * math.pi * t)
    world = np.stack([np.cos(yaw) * forward - np.sin(yaw) * lateral, np.sin(yaw) * forward + np.cos(yaw) * lateral], axis=1)
    yaw_rate = 0.5 + np.where(np.arange(len(t)) % 2 == 0, 0.1, -0.3)
    commands = np.tile([0.4, 0.0, 0.5], (len(t), 1))
    tracking = per_tick_tracking(world, yaw, yaw_rate, commands)
    assert tracking.tracking_rms_per_tick_heading_xy == pytest.approx(0.1 / math.sqrt(2), rel=1e-9)
    assert tracking.tracking_mean_abs_per_tick_heading_xy == pytest.approx(0.2 / math.pi, rel=1e-4)
    assert tracking.yaw_rate_rms_per_tick == pytest.approx(math.sqrt(0.05))
    assert tracking.yaw_rate_mean_abs_per_tick == pytest.approx(0.2)
    # One command for every tick gives the same figures as a command per tick.
    assert per_tick_tracking(world, yaw, yaw_rate, np.array([0.4, 0.0, 0.5])) == tracking


def test_no_ticks_give_nan() -> None:
    tracking = per_tick_tracking(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(3))
    assert tracking.ticks == 0 and math.isnan(tracking.tracking_rms_per_tick_heading_xy)
    assert set(tracking.summary()) == {"tracking_rms_per_tick_heading_xy", "tracking_mean_abs_per_tick_heading_xy",
                                       "yaw_rate_rms_per_tick", "yaw_rate_mean_abs_per_tick", "ticks"}
