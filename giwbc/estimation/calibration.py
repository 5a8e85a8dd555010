"""Standstill detection and what a still robot tells about its IMU (start-up calibration, zero-velocity updates).

A robot standing still on both feet is a calibration rig: its gyro reads its bias, its
accelerometer reads gravity (plus its bias), and its leg kinematics give the base tilt from flat
feet. :class:`StandstillDetector` decides, from the samples themselves, when that holds: samples
are summed in blocks of ``block_time``; a block is still when the gyro's and accelerometer's
spread are at noise level, the leg joints' mean positions did not move since the last block, and
both feet carried load throughout; ``blocks`` consecutive still blocks (``startup_blocks`` for the
start-up calibration's window, when the owner asks for a longer one) whose first and last mean
gyro agree to within what the sensors' noise explains, whose gravity direction turns slower than
``max_tilt_rate`` and whose leg joints did not move make a :class:`StandstillWindow`. A slow
rotation about a horizontal axis (a robot rocking on its soles moves no joint), which the gyro
alone cannot tell from a bias, shows as the turn of the gravity direction over the window (the
slope of a least-squares line through the blocks' mean specific force): where it is significant, :attr:`StandstillWindow.tilt_rate` carries it and
the gyro bias is the mean gyro less it (with both feet flat, the estimator reads the base's turn
from the leg encoders of the first and last block instead: a slow sway accelerates the IMU, which
would pass for a turn of gravity). Everything per sample is a few float additions; the tests run once
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

    block_time: float = 0.25  # s
    blocks: int = 3  # consecutive still blocks make a window
    startup_blocks: int | None = None  # ... the start-up calibration's window (None: blocks; longer: less gyro-bias noise)
    gyro_std: float = 0.05  # rad/s: largest spread of the gyro within a block
    accel_std: float = 0.35  # m/s^2: largest spread of the specific force within a block
    # Change of the block means between the window's first and last block: at most `noise_sigmas`
    # standard deviations of the difference of two means of noise, within [floor, cap].
    noise_sigmas: float = 3.0
    gyro_change: tuple[float, float] = (0.01, 0.02)  # rad/s
    max_tilt_rate: float = 0.02  # rad/s: the gravity direction turns slower than this
    joint_change: float = 1e-3  # rad: largest change of a leg joint's mean position across the window ...
    joint_rate: float = 1e-3  # rad/s: ... or this rate times the window's span, if larger (a PD-held robot creeps
    # slowly while it settles; the base's turn over the window is taken from the encoders, so a slow creep is harmless)
    min_load: float = 0.5  # both feet's load confidence stays above this (double support)

    def __post_init__(self) -> None:
        if self.block_time <= 0 or self.blocks < 2 or min(self.gyro_std, self.accel_std, self.joint_change) <= 0 or self.joint_rate < 0:
            raise ValueError("standstill thresholds and block_time must be > 0, blocks >= 2")
        if self.startup_blocks is not None and self.startup_blocks < 2:
            raise ValueError(f"standstill startup_blocks must be >= 2, got {self.startup_blocks}")
        for floor, cap in (self.gyro_change,):
            if not 0 < floor <= cap:
                raise ValueError("standstill change bounds need 0 < floor <= cap")


@dataclass(frozen=True)
class StandstillWindow:
    """Two still blocks: mean gyro and specific force (IMU frame), their spread, the leg joints'
    mean positions, the window's duration and sample count, and the time it ended."""

    gyro: np.ndarray
    accel: np.ndarray
    tilt_rate: np.ndarray  # rad/s, IMU frame: the rotation rate the gravity direction's turn shows (0 where not significant)
    gyro_std: np.ndarray
    accel_std: np.ndarray
    joint_positions: np.ndarray
    first_joints: np.ndarray  # the leg joints' mean positions in the first block ...
    last_joints: np.ndarray  # ... and in the last one
    span: float  # s between the first and the last block's centres
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
        if leg_joints is not None and len(leg_joints) and np.array_equal(leg_joints, np.arange(leg_joints[0], leg_joints[0] + len(leg_joints))):
            leg_joints = slice(int(leg_joints[0]), int(leg_joints[0]) + len(leg_joints))  # a view, not a gather
        self._leg_joints = leg_joints
        self.blocks = self.config.blocks  # still blocks a window needs (the owner may ask for more)
        self.reset()

    def reset(self) -> None:
        self._block: _Block | None = None
        self._still: list[tuple] = []  # (block, stats) of the last consecutive still blocks
        self.still = False  # the last blocks made a window
        self.rejection = "no block of samples yet"  # why the last block made no window (for a person)

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
        _, _, gyro_std, accel_std, _ = stats
        quiet = block.n >= 2 and block.min_load >= c.min_load and gyro_std.max() <= c.gyro_std and accel_std.max() <= c.accel_std
        self.still = False
        if not quiet:
            self._still = []
            self.rejection = (
                f"a foot unloaded (least load confidence {block.min_load:.2f} < {c.min_load})" if block.min_load < c.min_load
                else f"IMU not quiet (gyro spread {gyro_std.max():.3f} rad/s, accelerometer {accel_std.max():.3f} m/s^2)"
            )  # fmt: skip
            return None
        self._still = (self._still + [(block, stats)])[-self.blocks :]
        if len(self._still) < self.blocks:
            self.rejection = f"{len(self._still)} of {self.blocks} still blocks"
            return None
        (first, (g0, a0, gs0, as0, j0)), (last, (g1, a1, gs1, as1, j1)) = self._still[0], self._still[-1]
        root = math.sqrt(1.0 / first.n + 1.0 / last.n)  # std of a difference of two block means, per unit noise
        floor, cap = c.gyro_change
        if (np.abs(g1 - g0) > np.clip(c.noise_sigmas * root * np.maximum(gs0, gs1), floor, cap)).any():
            self.rejection = f"the mean gyro changed by {np.abs(g1 - g0).max():.4f} rad/s across the window (turning)"
            return None
        joint_limit = max(c.joint_change, c.joint_rate * (last.start - first.start))
        if np.abs(j1 - j0).max() > joint_limit:
            self.rejection = f"a leg joint moved by {np.abs(j1 - j0).max():.4f} rad across the window (limit {joint_limit:.4f})"
            return None
        # The turn of the gravity direction over the window, d(up)/dt = up x omega (so the omega
        # perpendicular to up is d(up)/dt x up): the slope of a least-squares line through the
        # blocks' mean specific force (weighted by their samples).
        counts = np.array([b.n for b, _ in self._still], float)
        weights = counts / counts.sum()
        centres = np.array([b.start for b, _ in self._still]) + 0.5 * c.block_time
        centres -= weights @ centres
        accels = np.array([st[1] for _, st in self._still])
        spread = max(float(weights @ (centres * centres)), 1e-12)
        mean_accel = weights @ accels
        norm = float(np.linalg.norm(mean_accel))
        up = mean_accel / norm
        rate = np.cross((weights * centres) @ (accels - mean_accel) / (spread * norm), up)  # the omega (perpendicular to up) that turns up so
        if np.linalg.norm(rate) > c.max_tilt_rate:
            self.rejection = f"the gravity direction turned at {np.linalg.norm(rate):.3f} rad/s (tilting)"
            return None
        accel_var = np.array([st[3] for _, st in self._still]) ** 2 / counts[:, None]  # of each block's mean
        rate_noise = 2.0 * math.sqrt(float(((weights * centres) ** 2 @ accel_var).max())) / (spread * norm)  # 2 sigma
        rate = np.where(np.abs(rate) > rate_noise, rate, 0.0)
        mean = [sum(w * st[k] for w, (_, st) in zip(weights, self._still)) for k in (0, 1, 4)]
        self.still = True
        self.rejection = ""
        return StandstillWindow(
            gyro=mean[0],
            accel=mean[1],
            tilt_rate=rate,
            gyro_std=np.max([st[2] for _, st in self._still], axis=0),
            accel_std=np.max([st[3] for _, st in self._still], axis=0),
            joint_positions=mean[2],
            first_joints=j0,
            last_joints=j1,
            span=float(centres[-1] - centres[0]),
            duration=time - first.start,
            samples=int(counts.sum()),
            end_time=time,
        )
