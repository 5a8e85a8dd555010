"""Standstill detection and what a still robot tells about its IMU (start-up calibration, zero-velocity updates).

A robot standing still on both feet is a calibration rig: its gyro reads its bias, its
accelerometer reads gravity (plus its bias), and its leg kinematics give the base tilt from flat
feet. :class:`StandstillDetector` decides, from the samples themselves, when that holds: samples
are summed in blocks of ``block_time``; a block is still when the gyro's and accelerometer's
spread are at noise level, the leg joints' mean positions did not move since the last block, and
both feet carried load throughout; two consecutive still blocks whose mean gyro and mean specific
force agree (a slow constant rotation shows as a change of the gravity direction between blocks)
make a :class:`StandstillWindow`. Everything per sample is a few float additions; the tests run once
per block.

:class:`CalibrationReport` is what the estimator found in its start-up calibration, for a log or
a person (``giwbc deploy`` prints :meth:`CalibrationReport.summary`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["CalibrationReport", "StandstillConfig", "StandstillDetector", "StandstillWindow"]


@dataclass(frozen=True)
class StandstillConfig:
    """Thresholds of standstill detection (per axis for the IMU, per joint for the legs)."""

    block_time: float = 0.25  # s: two still blocks make a window
    gyro_std: float = 0.05  # rad/s: largest spread of the gyro within a block
    accel_std: float = 0.35  # m/s^2: largest spread of the specific force within a block
    gyro_change: float = 0.01  # rad/s: largest change of the mean gyro between the two blocks
    accel_change: float = 0.05  # m/s^2: largest change of the mean specific force between them (0.02 rad/s of tilt rate)
    joint_change: float = 2e-3  # rad: largest change of a leg joint's mean position between them
    min_load: float = 0.5  # both feet's load confidence stays above this (double support)

    def __post_init__(self) -> None:
        if self.block_time <= 0 or min(self.gyro_std, self.accel_std, self.gyro_change, self.accel_change, self.joint_change) <= 0:
            raise ValueError("standstill thresholds and block_time must be > 0")


@dataclass(frozen=True)
class StandstillWindow:
    """Two still blocks: mean gyro and specific force (IMU frame), their spread, the leg joints'
    mean positions, the window's duration and sample count, and the time it ended."""

    gyro: np.ndarray
    accel: np.ndarray
    gyro_std: np.ndarray
    accel_std: np.ndarray
    joint_positions: np.ndarray
    duration: float
    samples: int
    end_time: float


@dataclass(frozen=True)
class CalibrationReport:
    """The start-up calibration: gyro bias and accelerometer bias (IMU frame), the base tilt it
    started from (roll, pitch, rad) and where it came from (``"feet"`` or ``"gravity"``), the tilt
    the accelerometer alone would have given (rad, the angle between the two), the offset of the
    IMU's orientation output from the calibrated orientation (rad, None without one), the
    standstill window it used, and when it finished."""

    time: float
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    roll: float
    pitch: float
    tilt_source: str
    accel_tilt_disagreement: float
    orientation_output_offset: float | None
    window_duration: float
    window_samples: int
    gyro_std: np.ndarray
    accel_std: np.ndarray

    def summary(self) -> str:
        """One line for a person."""
        deg = math.degrees
        offset = "" if self.orientation_output_offset is None else f", IMU orientation output off by {deg(self.orientation_output_offset):.2f} deg"
        return (
            f"IMU calibrated at t={self.time:.2f} s from {self.window_duration:.2f} s still ({self.window_samples} samples): "
            f"gyro bias {np.round(np.degrees(self.gyro_bias), 3).tolist()} deg/s, "
            f"accelerometer bias {np.round(self.accel_bias / 9.80665 * 1e3, 1).tolist()} mg, "
            f"tilt roll {deg(self.roll):.2f} pitch {deg(self.pitch):.2f} deg from {self.tilt_source} "
            f"(accelerometer alone: {deg(self.accel_tilt_disagreement):.2f} deg apart){offset}"
        )

    def as_dict(self) -> dict[str, object]:
        return {
            "time": self.time, "gyro_bias": self.gyro_bias.tolist(), "accel_bias": self.accel_bias.tolist(),
            "roll": self.roll, "pitch": self.pitch, "tilt_source": self.tilt_source,
            "accel_tilt_disagreement": self.accel_tilt_disagreement,
            "orientation_output_offset": self.orientation_output_offset, "window_duration": self.window_duration,
            "window_samples": self.window_samples, "gyro_std": self.gyro_std.tolist(), "accel_std": self.accel_std.tolist(),
        }  # fmt: skip


class _Block:
    """Sums over one block of samples."""

    __slots__ = ("start", "n", "sums", "joints", "min_load")

    def __init__(self, start: float, joints: int) -> None:
        self.start = start
        self.n = 0
        self.sums = [0.0] * 12  # gyro, accel, gyro^2, accel^2
        self.joints = np.zeros(joints)
        self.min_load = 1.0

    def stats(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        n = max(self.n, 1)
        sums = np.array(self.sums) / n
        mean = sums[:6]
        std = np.sqrt(np.maximum(sums[6:] - mean * mean, 0.0))
        return mean[:3], mean[3:], std[:3], std[3:], self.joints / n


class StandstillDetector:
    """Finds windows of standstill in a stream of IMU samples and leg joint positions (module doc)."""

    def __init__(self, config: StandstillConfig | None = None, leg_joints: np.ndarray | None = None) -> None:
        self.config = config if config is not None else StandstillConfig()
        self._leg_joints = leg_joints
        self.reset()

    def reset(self) -> None:
        self._block: _Block | None = None
        self._last: tuple | None = None  # stats of the last still block
        self._last_block_time = 0.0
        self.still = False  # the last two blocks made a window

    def add(self, time: float, gyro: Sequence[float], accel: Sequence[float], joint_positions: np.ndarray, load: float) -> StandstillWindow | None:
        """One sample (``load``: the least loaded foot's confidence, 0 when a foot is off the
        ground). Returns a window when this sample completed one, else None."""
        block = self._block
        legs = joint_positions if self._leg_joints is None else joint_positions[self._leg_joints]
        if block is None:
            block = self._block = _Block(time, len(legs))
        gx, gy, gz = gyro
        ax, ay, az = accel
        s = block.sums
        s[0] += gx; s[1] += gy; s[2] += gz; s[3] += ax; s[4] += ay; s[5] += az  # noqa: E702
        s[6] += gx * gx; s[7] += gy * gy; s[8] += gz * gz; s[9] += ax * ax; s[10] += ay * ay; s[11] += az * az  # noqa: E702
        block.joints += legs
        block.n += 1
        if load < block.min_load:
            block.min_load = load
        if time - block.start < self.config.block_time:
            return None
        self._block = None
        return self._finish(block, time)

    def _finish(self, block: _Block, time: float) -> StandstillWindow | None:
        c = self.config
        stats = block.stats()
        gyro, accel, gyro_std, accel_std, joints = stats
        quiet = block.n >= 2 and block.min_load >= c.min_load and gyro_std.max() <= c.gyro_std and accel_std.max() <= c.accel_std
        last, self._last = self._last, ((block, stats, time) if quiet else None)
        self.still = False
        if not quiet or last is None:
            return None
        last_block, (g0, a0, gs0, as0, j0), _ = last
        if (
            np.abs(gyro - g0).max() > c.gyro_change
            or np.abs(accel - a0).max() > c.accel_change
            or np.abs(joints - j0).max() > c.joint_change
        ):
            return None
        n0, n1 = last_block.n, block.n
        n = n0 + n1
        self.still = True
        return StandstillWindow(
            gyro=(n0 * g0 + n1 * gyro) / n,
            accel=(n0 * a0 + n1 * accel) / n,
            gyro_std=np.maximum(gs0, gyro_std),
            accel_std=np.maximum(as0, accel_std),
            joint_positions=(n0 * j0 + n1 * joints) / n,
            duration=time - last_block.start,
            samples=n,
            end_time=time,
        )
