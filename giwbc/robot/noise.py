"""Sensor noise and latency: what a real robot's IMU, encoders and torque estimates add to the truth.

:class:`NoisyRobot` wraps any :class:`~giwbc.robot.interface.Robot` (a ``MujocoRobot`` in
simulation) and reports only what a robot on a CAN bus measures, corrupted by a
:class:`SensorNoiseConfig`: the IMU (orientation, gyro, accelerometer) and the joints (positions,
velocities, efforts). Commands pass through unchanged.

What it does *not* report: the base pose and twist, link poses and contact wrenches. On hardware
nothing measures them, so :meth:`NoisyRobot.base_state`, :meth:`~NoisyRobot.link_pose`,
:meth:`~NoisyRobot.contact_wrench` (and hence ``generalized_state``) raise
:class:`NotMeasuredError`; a state estimator (:mod:`giwbc.robot.estimator`) provides them, and
the truth stays reachable for evaluation as :attr:`NoisyRobot.ground_truth`.

Sampling: the wrapper takes one sample of every channel per distinct ``robot.time()`` it is read
at; latency counts those samples. Every random draw goes through the ``numpy.random.Generator``
given to it, in a fixed order per sample, so the same seed and the same read times give the same
noise.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass, fields

import numpy as np

from giwbc.robot.estimation.so3 import quat_multiply
from giwbc.robot.interface import BaseState, ContactWrench, ImpedanceCommand, ImuReading, Robot

__all__ = ["NoisyRobot", "NotMeasuredError", "SensorNoiseConfig"]


class NotMeasuredError(RuntimeError):
    """A quantity a real robot does not measure (base pose/twist, link poses, contact wrenches)."""


@dataclass(frozen=True)
class SensorNoiseConfig:
    """Noise, bias, latency and range of the sensors of a CAN robot; defaults: a G1-class robot.

    White noise is given as a density and turned into a per-sample standard deviation with the
    nominal ``sample_period`` (``std = density / sqrt(sample_period)``); bias random walks use the
    elapsed time between samples. Constant biases are drawn once per wrapper (turn-on bias).
    """

    sample_period: float = 0.002  # s, nominal output period of the sensors
    gyro_noise_density: float = 5e-4  # rad/s/sqrt(Hz)   (0.011 rad/s per sample at 500 Hz)
    gyro_bias: float = 5e-3  # rad/s, std of the constant turn-on bias per axis
    gyro_bias_random_walk: float = 1e-4  # rad/s/sqrt(s)
    accel_noise_density: float = 2e-3  # m/s^2/sqrt(Hz)  (0.045 m/s^2 per sample at 500 Hz)
    accel_bias: float = 0.05  # m/s^2, std of the constant turn-on bias per axis
    accel_bias_random_walk: float = 1e-3  # m/s^2/sqrt(s)
    orientation_noise: float = 0.005  # rad, std per axis of the IMU's own orientation output
    joint_position_noise: float = 5e-4  # rad
    joint_velocity_noise: float = 0.03  # rad/s
    joint_effort_noise: float = 0.5  # N m
    encoder_resolution: float = 0.0  # rad, quantization step of joint positions (0: none)
    imu_latency: int = 1  # samples
    joint_latency: int = 1  # samples
    gyro_range: float = math.radians(2000.0)  # rad/s, per-axis saturation (+-2000 deg/s)
    accel_range: float = 16.0 * 9.80665  # m/s^2, per-axis saturation (+-16 g)
    imu_dropout: float = 0.0  # probability an IMU sample is not refreshed (repeats the last one)

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not value >= 0:
                raise ValueError(f"SensorNoiseConfig.{item.name} must be a number >= 0, got {value!r}")
        for name in ("imu_latency", "joint_latency"):
            if int(getattr(self, name)) != getattr(self, name):
                raise ValueError(f"SensorNoiseConfig.{name} counts samples: it must be an integer")
        if self.sample_period <= 0 or self.gyro_range <= 0 or self.accel_range <= 0:
            raise ValueError("sample_period, gyro_range and accel_range must be > 0")
        if self.imu_dropout >= 1:
            raise ValueError("imu_dropout is a probability below 1")

    @classmethod
    def ideal(cls) -> "SensorNoiseConfig":
        """Perfect sensors: no noise, no bias, no latency, unbounded range."""
        zero = {item.name: 0.0 for item in fields(cls) if item.name not in ("sample_period", "gyro_range", "accel_range")}
        return cls(**{**zero, "imu_latency": 0, "joint_latency": 0, "gyro_range": math.inf, "accel_range": math.inf})

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True)
class _Sample:
    """Every measured channel at one time: what one read of the sensors returns."""

    imu: ImuReading
    positions: np.ndarray
    velocities: np.ndarray
    efforts: np.ndarray


class _ImuNoise:
    """Turns a true IMU reading into a measured one: bias, white noise, saturation."""

    def __init__(self, config: SensorNoiseConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.gyro_bias = config.gyro_bias * rng.standard_normal(3)
        self.accel_bias = config.accel_bias * rng.standard_normal(3)
        root = 1.0 / math.sqrt(config.sample_period)
        self._gyro_std, self._accel_std = config.gyro_noise_density * root, config.accel_noise_density * root

    def measure(self, truth: ImuReading, elapsed: float, draws: np.ndarray) -> ImuReading:
        """``draws``: 15 standard normals (gyro, gyro walk, accel, accel walk, orientation)."""
        c, walk = self.config, math.sqrt(max(elapsed, 0.0))
        self.gyro_bias = self.gyro_bias + c.gyro_bias_random_walk * walk * draws[3:6]
        self.accel_bias = self.accel_bias + c.accel_bias_random_walk * walk * draws[9:12]
        gyro = np.asarray(truth.angular_velocity, float) + self.gyro_bias + self._gyro_std * draws[0:3]
        accel = np.asarray(truth.linear_acceleration, float) + self.accel_bias + self._accel_std * draws[6:9]
        return ImuReading(
            _perturb(np.asarray(truth.quaternion, float), c.orientation_noise * draws[12:15]),
            np.minimum(np.maximum(gyro, -c.gyro_range), c.gyro_range),
            np.minimum(np.maximum(accel, -c.accel_range), c.accel_range),
            truth.time,
        )


def _perturb(quaternion: np.ndarray, rotation_vector: np.ndarray) -> np.ndarray:
    """``quaternion`` rotated by a small body-frame rotation vector."""
    angle = float(np.linalg.norm(rotation_vector))
    if angle == 0.0:
        return quaternion.copy()
    half = 0.5 * angle
    delta = np.concatenate([math.sin(half) / angle * rotation_vector, [math.cos(half)]])
    return quat_multiply(quaternion, delta)


class NoisyRobot(Robot):
    """A :class:`Robot` reporting what a real robot measures, with noise and latency; see the module doc.

    ``ground_truth`` is the wrapped robot: step and reset the simulation through it, and read it
    to evaluate an estimator. A wrapped robot whose time goes backwards (a reset) restarts the
    latency buffers; biases persist, as they would across a controller restart.
    """

    def __init__(self, robot: Robot, config: SensorNoiseConfig | None = None, rng: np.random.Generator | None = None) -> None:
        if rng is None:
            raise ValueError("NoisyRobot needs a seeded numpy.random.Generator (rng=np.random.default_rng(seed))")
        self.ground_truth = robot
        self.config = config if config is not None else SensorNoiseConfig()
        self._rng = rng
        self._imu_noise = _ImuNoise(self.config, rng)
        self._dofs = robot.dofs
        self._buffer: deque[_Sample] = deque(maxlen=int(max(self.config.imu_latency, self.config.joint_latency)) + 1)
        self._sample_time: float | None = None

    # --- identity -------------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.ground_truth.name

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.ground_truth.joint_names

    @property
    def floating_base(self) -> bool:
        return self.ground_truth.floating_base

    def time(self) -> float:
        return self.ground_truth.time()

    # --- measured ---------------------------------------------------------------------------
    def imu(self) -> ImuReading:
        return self._delayed(self.config.imu_latency).imu

    def joint_positions(self) -> np.ndarray:
        return self._delayed(self.config.joint_latency).positions.copy()

    def joint_velocities(self) -> np.ndarray:
        return self._delayed(self.config.joint_latency).velocities.copy()

    def joint_efforts(self) -> np.ndarray:
        return self._delayed(self.config.joint_latency).efforts.copy()

    # --- not measured on hardware -------------------------------------------------------------
    def base_state(self) -> BaseState:
        raise NotMeasuredError(
            "a real robot does not measure its base state: estimate it (giwbc.robot.estimator.StateEstimator, "
            "or EstimatedRobot), or read noisy.ground_truth.base_state() to evaluate"
        )

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        raise NotMeasuredError(f"link poses need the base pose, which a real robot does not measure (link {link!r})")

    def contact_wrench(self, link: str) -> ContactWrench:
        raise NotMeasuredError(f"this robot has no force/torque sensor at {link!r}: estimate contacts from joint efforts")

    # --- commands -------------------------------------------------------------------------
    def set_joint_torques(self, torques: np.ndarray) -> None:
        self.ground_truth.set_joint_torques(torques)

    def set_joint_impedance(self, command: ImpedanceCommand) -> None:
        self.ground_truth.set_joint_impedance(command)

    # --- sampling -------------------------------------------------------------------------
    def _delayed(self, latency: int) -> _Sample:
        self._refresh()
        return self._buffer[max(0, len(self._buffer) - 1 - int(latency))]

    def _refresh(self) -> None:
        """Take a new sample when the wrapped robot's time has moved since the last one."""
        now = self.ground_truth.time()
        if self._sample_time is not None and now == self._sample_time:
            return
        if self._sample_time is not None and now < self._sample_time:
            self._buffer.clear()
        elapsed = 0.0 if self._sample_time is None or not self._buffer else now - self._sample_time
        self._sample_time = now
        self._buffer.append(self._sample(elapsed))

    def _sample(self, elapsed: float) -> _Sample:
        robot, c, n = self.ground_truth, self.config, self._dofs
        draws = self._rng.standard_normal(15 + 3 * n)
        dropped = self._rng.random() < c.imu_dropout
        imu = self._imu_noise.measure(robot.imu(), elapsed, draws[:15])
        if dropped and self._buffer:
            imu = self._buffer[-1].imu
        positions = robot.joint_positions() + c.joint_position_noise * draws[15 : 15 + n]
        if c.encoder_resolution > 0:
            positions = np.round(positions / c.encoder_resolution) * c.encoder_resolution
        velocities = robot.joint_velocities() + c.joint_velocity_noise * draws[15 + n : 15 + 2 * n]
        efforts = robot.joint_efforts() + c.joint_effort_noise * draws[15 + 2 * n :]
        return _Sample(imu, positions, velocities, efforts)
