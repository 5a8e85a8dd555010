"""Velocity tracking scored per control tick in the heading frame, as the RL frameworks score it.

mjlab's ``track_lin_vel_xy`` (and Isaac Lab's) compares, at every control step, the base's
*instantaneous* linear velocity rotated into the heading frame (the base yaw alone: world z up,
x along the base's heading) with the command; the yaw rate is the base angular velocity about
the vertical. The within-step sway of a gait counts in full there, whereas the per-step average
of :mod:`giwbc.locomotion.simulation` (base displacement from touch-down to touch-down) averages
it out. Both are legitimate; a figure must say which it is: this module's keys all end in
``per_tick_heading_xy`` (linear) or ``per_tick`` (yaw rate).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class TickTracking:
    """Per-tick heading-frame tracking errors over a run's scored ticks (nan when none)."""

    tracking_rms_per_tick_heading_xy: float  # m/s: sqrt(mean ‖v_xy,heading − v_cmd,xy‖²)
    tracking_mean_abs_per_tick_heading_xy: float  # m/s: mean ‖v_xy,heading − v_cmd,xy‖
    yaw_rate_rms_per_tick: float  # rad/s: sqrt(mean (ω_z − ω_cmd)²)
    yaw_rate_mean_abs_per_tick: float  # rad/s: mean |ω_z − ω_cmd|
    ticks: int

    def summary(self) -> dict[str, float | int]:
        return asdict(self)


def heading_frame_velocity(velocity_xy_world: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """World-frame xy velocities ``(n, 2)`` rotated into the heading frames of the yaws ``(n,)``."""
    v = np.asarray(velocity_xy_world, dtype=float).reshape(-1, 2)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1]], axis=1)


def per_tick_tracking(velocity_xy_world: np.ndarray, yaw: np.ndarray, yaw_rate: np.ndarray, commands: np.ndarray) -> TickTracking:
    """Errors of every sampled tick: base xy velocity (world, ``(n, 2)``) in the heading frame of the
    base yaw ``(n,)`` against the command's ``(vx, vy)``, and the vertical angular velocity ``(n,)``
    against its yaw rate; ``commands`` is ``(n, 3)`` or one ``(3,)`` held throughout."""
    yaw = np.asarray(yaw, dtype=float).reshape(-1)
    n = len(yaw)
    if n == 0:
        return TickTracking(math.nan, math.nan, math.nan, math.nan, 0)
    commands = np.broadcast_to(np.asarray(commands, dtype=float), (n, 3))
    xy = np.linalg.norm(heading_frame_velocity(velocity_xy_world, yaw) - commands[:, :2], axis=1)
    wz = np.abs(np.asarray(yaw_rate, dtype=float).reshape(-1) - commands[:, 2])
    return TickTracking(float(np.sqrt(np.mean(xy**2))), float(np.mean(xy)), float(np.sqrt(np.mean(wz**2))), float(np.mean(wz)), n)


__all__ = ["TickTracking", "heading_frame_velocity", "per_tick_tracking"]
