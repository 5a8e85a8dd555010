"""Sensor noise and latency: what a real robot's IMU, encoders and torque estimates add to the truth.

The one implementation of sensor errors in giwbc is :class:`SensorModel`: bias (constant plus
random walk), white noise, encoder quantization, saturation, IMU dropout and latency, IMU mounting
misalignment, errors of the IMU's own orientation output (constant tilt bias, heading drift) and
sample-time jitter, applied to true readings sampled from a robot. IMUs people actually mount are
named profiles (:data:`IMU_PROFILES`, :meth:`SensorNoiseConfig.profile`): ``ahrs`` (an IMU with
its own orientation output), ``mems`` (gyro and accelerometer only, datasheet turn-on biases) and
``cheap``. Two wrappers use it:

* :class:`NoisyRobot` wraps any :class:`~giwbc.robot.interface.Robot` (a ``MujocoRobot`` in
  simulation) and reports only what a robot on a CAN bus measures, with the errors of a
  :class:`SensorNoiseConfig` (noise densities, turn-on biases drawn once): the IMU and the joints.
  It does *not* report the base pose and twist, link poses and contact wrenches: on hardware
  nothing measures them, so :meth:`NoisyRobot.base_state`, :meth:`~NoisyRobot.link_pose`,
  :meth:`~NoisyRobot.contact_wrench` (and hence ``generalized_state``) raise
  :class:`NotMeasuredError`; a state estimator (:mod:`giwbc.estimation.estimator`) provides them, and
  the truth stays reachable for evaluation as :attr:`NoisyRobot.robot`.
* :class:`~giwbc.randomization.PerturbedRobot` builds a :class:`SensorModel` from each episode's
  randomized noise and bias (:func:`giwbc.randomization.perturbed.sensor_errors`) and passes the ground truth through.

Sampling: a model takes one sample of every channel per distinct ``robot.time()`` it is read at
(or per physics step, when its owner records every step); latency counts those samples. Every
random draw goes through the ``numpy.random.Generator`` given to it, in a fixed order per sample,
so the same seed and the same read times give the same noise.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields

import numpy as np

from giwbc.robot.so3 import exp, matrix_to_quat
from giwbc.robot.interface import BaseState, ContactWrench, ImuReading, Robot, RobotWrapper
from giwbc.errors import NotMeasuredError
from giwbc.util.jit import compiled

__all__ = ["IMU_PROFILES", "NoisyRobot", "NotMeasuredError", "SensorErrors", "SensorModel", "SensorNoiseConfig"]

MIT_POSITION_RANGE = 25.0  # rad: the MIT frame's position field spans +-12.5 rad
MIT_ENCODER_RESOLUTION = MIT_POSITION_RANGE / (2**16 - 1)  # rad: its 16-bit quantization step


@dataclass(frozen=True)
class SensorErrors:
    """Per-sample error parameters of every channel: standard deviations, biases, ranges, latencies.

    Joint entries are scalars or one value per joint; IMU biases are 3-vectors (the initial bias,
    which then random-walks by ``*_bias_walk`` per sqrt(second) of elapsed time).
    """

    joint_position_noise: np.ndarray | float = 0.0  # rad
    joint_position_bias: np.ndarray | float = 0.0  # rad
    joint_velocity_noise: np.ndarray | float = 0.0  # rad/s
    joint_effort_noise: np.ndarray | float = 0.0  # N m
    encoder_resolution: float = 0.0  # rad (0: no quantization)
    gyro_noise: float = 0.0  # rad/s
    gyro_bias: np.ndarray | float = 0.0  # rad/s
    gyro_bias_walk: float = 0.0  # rad/s/sqrt(s)
    accel_noise: float = 0.0  # m/s^2
    accel_bias: np.ndarray | float = 0.0  # m/s^2
    accel_bias_walk: float = 0.0  # m/s^2/sqrt(s)
    orientation_noise: float = 0.0  # rad per axis
    gyro_range: float = math.inf  # rad/s, per-axis saturation
    accel_range: float = math.inf  # m/s^2
    imu_dropout: float = 0.0  # probability a sample repeats the previous IMU sample
    imu_latency: int = 0  # samples
    joint_latency: int = 0  # samples
    orientation_output: bool = True  # False: the IMU reports no orientation (its quaternion is NaN)
    orientation_bias: np.ndarray | float = 0.0  # rad, world-frame rotation vector of the orientation output's constant error
    heading_drift: float = 0.0  # rad/s, the orientation output's heading error grows at this rate
    mounting: np.ndarray | float = 0.0  # rad, rotation vector of the IMU's actual frame in its nominal one
    sample_jitter: float = 0.0  # s, std of the IMU timestamp's error (clipped to +-0.4 sample)
    sample_period: float = 0.002  # s, nominal (bounds the jitter)

    @property
    def latency(self) -> int:
        return int(max(self.imu_latency, self.joint_latency))

    def is_ideal(self) -> bool:
        """No error at all: readings are the truth (a wrapper may then skip the model)."""
        arrays = (self.joint_position_noise, self.joint_position_bias, self.joint_velocity_noise, self.joint_effort_noise,
                  self.gyro_bias, self.accel_bias, self.orientation_bias, self.mounting)
        scalars = (self.encoder_resolution, self.gyro_noise, self.gyro_bias_walk, self.accel_noise, self.accel_bias_walk,
                   self.orientation_noise, self.imu_dropout, self.latency, self.heading_drift, self.sample_jitter,
                   not self.orientation_output)
        ranges = (self.gyro_range, self.accel_range)
        return not any(np.any(a) for a in arrays) and not any(scalars) and all(r == math.inf for r in ranges)


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
    # Errors of real IMUs (0 by default: the model the estimator was first built against).
    orientation_output: bool = True  # the IMU reports its own orientation (an AHRS); False: gyro + accelerometer only
    orientation_bias: float = 0.0  # rad, std per axis (roll, pitch) of the orientation output's constant tilt error
    heading_drift: float = 0.0  # rad/s, std of the orientation output's heading drift rate
    mounting_misalignment: float = 0.0  # rad, std per axis of the IMU's mounting error (drawn at turn-on)
    sample_jitter: float = 0.0  # s, std of the IMU timestamp's error

    def __post_init__(self) -> None:
        if not isinstance(self.orientation_output, bool):
            raise ValueError(f"SensorNoiseConfig.orientation_output must be a bool, got {self.orientation_output!r}")
        for item in fields(self):
            if item.name == "orientation_output":
                continue
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
        skip = ("sample_period", "gyro_range", "accel_range", "orientation_output")
        zero = {item.name: 0.0 for item in fields(cls) if item.name not in skip}
        return cls(**{**zero, "imu_latency": 0, "joint_latency": 0, "gyro_range": math.inf, "accel_range": math.inf})

    @classmethod
    def profile(cls, name: str, **overrides: object) -> "SensorNoiseConfig":
        """The sensors of a named IMU class (:data:`IMU_PROFILES`), fields replaced by ``overrides``."""
        if name not in IMU_PROFILES:
            raise ValueError(f"unknown IMU profile {name!r}; known: {sorted(IMU_PROFILES)}")
        return cls(**{**IMU_PROFILES[name], **overrides})  # type: ignore[arg-type]

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    def errors(self, rng: np.random.Generator) -> SensorErrors:
        """Per-sample errors: densities over the sample period; turn-on biases drawn now (gyro, then
        accelerometer, then, only when their std is not 0, mounting, orientation bias, heading drift)."""
        root = 1.0 / math.sqrt(self.sample_period)
        gyro_bias = self.gyro_bias * rng.standard_normal(3)
        accel_bias = self.accel_bias * rng.standard_normal(3)
        mounting = self.mounting_misalignment * rng.standard_normal(3) if self.mounting_misalignment else 0.0
        orientation_bias = 0.0
        if self.orientation_bias:
            orientation_bias = np.append(self.orientation_bias * rng.standard_normal(2), 0.0)  # roll, pitch
        drift = float(self.heading_drift * rng.standard_normal()) if self.heading_drift else 0.0
        return SensorErrors(
            joint_position_noise=self.joint_position_noise,
            joint_velocity_noise=self.joint_velocity_noise,
            joint_effort_noise=self.joint_effort_noise,
            encoder_resolution=self.encoder_resolution,
            gyro_noise=self.gyro_noise_density * root,
            gyro_bias=gyro_bias,
            gyro_bias_walk=self.gyro_bias_random_walk,
            accel_noise=self.accel_noise_density * root,
            accel_bias=accel_bias,
            accel_bias_walk=self.accel_bias_random_walk,
            orientation_noise=self.orientation_noise,
            gyro_range=self.gyro_range,
            accel_range=self.accel_range,
            imu_dropout=self.imu_dropout,
            imu_latency=int(self.imu_latency),
            joint_latency=int(self.joint_latency),
            orientation_output=self.orientation_output,
            orientation_bias=orientation_bias,
            heading_drift=drift,
            mounting=mounting,
            sample_jitter=self.sample_jitter,
            sample_period=self.sample_period,
        )


_G = 9.80665
_DEG = math.pi / 180.0
# Named IMU classes (SensorNoiseConfig fields). Turn-on biases are datasheet 1-sigma figures; all
# three sit on the same actuators: MIT-frame 16-bit positions, 1-sample joint latency.
IMU_PROFILES: dict[str, dict[str, object]] = {
    # An IMU with its own orientation output (AHRS, e.g. industrial grade): 0.5 deg/s gyro and
    # 5 mg accelerometer turn-on bias, orientation output off by 0.3 deg in tilt and drifting
    # 0.5 deg/min in heading, mounted within 0.2 deg, 1-sample latency.
    "ahrs": dict(
        gyro_bias=0.5 * _DEG, accel_bias=0.005 * _G, orientation_noise=0.005, orientation_bias=0.3 * _DEG,
        heading_drift=0.5 * _DEG / 60.0, mounting_misalignment=0.2 * _DEG, sample_jitter=2e-5,
        encoder_resolution=MIT_ENCODER_RESOLUTION, imu_latency=1, joint_latency=1,
    ),
    # A MEMS IMU without orientation output (gyro + accelerometer): 0.5 deg/s and 20 mg turn-on
    # bias, 2-sample latency, 1 % dropouts, mounted within 0.2 deg, 50 us timestamp jitter.
    "mems": dict(
        orientation_output=False, gyro_bias=0.5 * _DEG, accel_bias=0.020 * _G, orientation_noise=0.0,
        mounting_misalignment=0.2 * _DEG, sample_jitter=5e-5, imu_dropout=0.01,
        encoder_resolution=MIT_ENCODER_RESOLUTION, imu_latency=2, joint_latency=1,
    ),
    # A cheap MEMS IMU: 2 deg/s and 60 mg turn-on bias, twice the noise and bias walk, mounted
    # within 0.5 deg, 2-sample latency, 2 % dropouts, 100 us jitter.
    "cheap": dict(
        orientation_output=False, gyro_bias=2.0 * _DEG, accel_bias=0.060 * _G, orientation_noise=0.0,
        gyro_noise_density=1e-3, gyro_bias_random_walk=2e-4, accel_noise_density=4e-3, accel_bias_random_walk=2e-3,
        mounting_misalignment=0.5 * _DEG, sample_jitter=1e-4, imu_dropout=0.02,
        encoder_resolution=MIT_ENCODER_RESOLUTION, imu_latency=2, joint_latency=1,
    ),
}


class _Sample:
    """Every measured channel at one time: what one read of the sensors returns (one per physics
    step: a slotted class, not a frozen dataclass, whose ``__init__`` costs 4 ``object.__setattr__``)."""

    __slots__ = ("imu", "positions", "velocities", "efforts")

    def __init__(self, imu: ImuReading | None, positions: np.ndarray, velocities: np.ndarray, efforts: np.ndarray) -> None:
        self.imu, self.positions, self.velocities, self.efforts = imu, positions, velocities, efforts


class SensorModel:
    """Turns a robot's true readings into measured ones, one sample per distinct robot time.

    ``imu=False`` for a robot without an IMU (its joints are still measured). A time going
    backwards (a reset) restarts the latency buffer; biases persist, as they would across a
    controller restart. :meth:`record` forces a sample now (an owner calling it after every physics
    step makes latency count physics steps).
    """

    def __init__(self, robot: Robot, errors: SensorErrors, rng: np.random.Generator, *, imu: bool = True) -> None:
        self.robot = robot
        self.errors = errors
        self._rng = rng
        self._imu = imu
        self._dofs = robot.dofs
        # The IMU's state (biases, random-walked in place) and constants as arrays for the compiled
        # sample (_measure_imu_kernel): one sample per physics step, where numpy's per-call overhead on
        # 3-vectors would cost more than the arithmetic.
        self._gyro_bias = np.broadcast_to(np.asarray(errors.gyro_bias, dtype=float), (3,)).copy()
        self._accel_bias = np.broadcast_to(np.asarray(errors.accel_bias, dtype=float), (3,)).copy()
        mounting = np.broadcast_to(np.asarray(errors.mounting, dtype=float), (3,))
        self._mounting = exp(mounting) if mounting.any() else None  # actual IMU frame in the nominal one
        self._mounting_quaternion = matrix_to_quat(self._mounting) if self._mounting is not None else None
        self._orientation_bias = np.broadcast_to(np.asarray(errors.orientation_bias, dtype=float), (3,)).copy()
        self._orientation_error = bool(self._orientation_bias.any() or errors.heading_drift)
        # [0:9] the mounting rotation (row by row), [9:13] its quaternion, [13:16] the orientation output's
        # bias; then heading drift, gyro and accel bias walks, noises and ranges, orientation noise
        self._imu_constants = np.concatenate([
            self._mounting.reshape(-1) if self._mounting is not None else np.eye(3).reshape(-1),
            self._mounting_quaternion if self._mounting_quaternion is not None else (0.0, 0.0, 0.0, 1.0),
            self._orientation_bias,
            (errors.heading_drift, errors.gyro_bias_walk, errors.accel_bias_walk, errors.gyro_noise, errors.accel_noise,
             errors.gyro_range, errors.accel_range, errors.orientation_noise),
        ]).astype(float)
        self._imu_flags = (self._mounting is not None, bool(errors.orientation_output), self._orientation_error)
        self._joint_bias = np.broadcast_to(np.asarray(errors.joint_position_bias, dtype=float), (self._dofs,)).copy()
        self._joint_bias_any = bool(self._joint_bias.any())
        # The joints' three noise stds as one (3, dofs) array: one product with the draws' (3, dofs) view.
        self._joint_noise = np.stack([np.broadcast_to(np.asarray(std, dtype=float), (self._dofs,))
                                      for std in (errors.joint_position_noise, errors.joint_velocity_noise, errors.joint_effort_noise)])
        self._draw_count = 15 + 3 * self._dofs
        self._buffer: deque[_Sample] = deque(maxlen=errors.latency + 1)
        self._sample_time: float | None = None
        self._warm_up()

    def _warm_up(self) -> None:
        """Run the compiled sample once now, on copies (no draw taken, no state changed): the first
        call in a process compiles it or loads it from numba's cache, which must not happen in a
        real-time loop (the actuator emulator samples its IMU in one)."""
        draws, n = np.zeros(self._draw_count), self._dofs
        _measure_imu_kernel(np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3), 0.0, 0.0, draws[:15], self._gyro_bias.copy(),
                            self._accel_bias.copy(), self._imu_constants, *self._imu_flags, np.empty(10))
        _measure_joints(draws, self._joint_noise, np.zeros(n), self._joint_bias, self._joint_bias_any, 0.0, np.zeros(n), np.zeros(n),
                        np.empty((3, n)))

    @property
    def gyro_bias(self) -> np.ndarray:
        """The gyro's bias now (rad/s, IMU frame): the turn-on bias plus its random walk so far."""
        return self._gyro_bias.copy()

    @gyro_bias.setter
    def gyro_bias(self, value: np.ndarray) -> None:
        self._gyro_bias = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()

    @property
    def accel_bias(self) -> np.ndarray:
        """The accelerometer's bias now (m/s^2, IMU frame)."""
        return self._accel_bias.copy()

    @accel_bias.setter
    def accel_bias(self, value: np.ndarray) -> None:
        self._accel_bias = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()

    def restart(self) -> None:
        """Forget the buffered samples (the robot was reset)."""
        self._buffer.clear()
        self._sample_time = None

    # --- reads ------------------------------------------------------------------------------
    def imu(self) -> ImuReading:
        reading = self._delayed(self.errors.imu_latency).imu
        if reading is None:
            return self.robot.imu()  # the robot's own error: it has no IMU
        return reading

    def joint_positions(self) -> np.ndarray:
        return self._delayed(self.errors.joint_latency).positions.copy()

    def joint_velocities(self) -> np.ndarray:
        return self._delayed(self.errors.joint_latency).velocities.copy()

    def joint_efforts(self) -> np.ndarray:
        return self._delayed(self.errors.joint_latency).efforts.copy()

    # --- sampling -------------------------------------------------------------------------
    def _delayed(self, latency: int) -> _Sample:
        self._refresh()
        return self._buffer[max(0, len(self._buffer) - 1 - int(latency))]

    def _refresh(self) -> None:
        """Take a new sample when the robot's time has moved since the last one."""
        if self._sample_time is None or self.robot.time() != self._sample_time:
            self.record()

    def record(self) -> None:
        """Sample every channel now."""
        now = self.robot.time()
        if self._sample_time is not None and now < self._sample_time:
            self._buffer.clear()
        elapsed = 0.0 if self._sample_time is None or not self._buffer else now - self._sample_time
        self._sample_time = now
        self._buffer.append(self._sample(elapsed))

    def _sample(self, elapsed: float) -> _Sample:
        robot, e, n = self.robot, self.errors, self._dofs
        rng = self._rng
        draws = rng.standard_normal(self._draw_count)  # fixed order: IMU (15), positions, velocities, efforts
        dropped = rng.random() < e.imu_dropout
        jitter = 0.0
        if e.sample_jitter:
            bound = 0.4 * e.sample_period
            jitter = min(bound, max(-bound, e.sample_jitter * float(rng.standard_normal())))
        imu = None
        if self._imu:
            imu = self._measure_imu(robot.imu(), elapsed, draws[:15], jitter)
            if dropped and self._buffer:
                imu = self._buffer[-1].imu
        joints = np.empty((3, n))  # positions, velocities, efforts: one array, read through views
        _measure_joints(draws, self._joint_noise, robot.joint_positions(), self._joint_bias, self._joint_bias_any,
                        float(e.encoder_resolution), robot.joint_velocities(), robot.joint_efforts(), joints)
        return _Sample(imu, joints[0], joints[1], joints[2])

    def _measure_imu(self, truth: ImuReading, elapsed: float, draws: Sequence[float], jitter: float = 0.0) -> ImuReading:
        """``draws``: 15 standard normals (gyro, gyro walk, accel, accel walk, orientation);
        ``jitter``: the timestamp's error (s). One compiled call (:func:`_measure_imu_kernel`), the
        same arithmetic as the numpy reference in tests/test_sensor_noise.py."""
        values = np.empty(10)  # one array for the three channels, read through views (one allocation instead of three)
        mounted, output, tilted = self._imu_flags
        _measure_imu_kernel(np.asarray(truth.quaternion, float), np.asarray(truth.angular_velocity, float),
                            np.asarray(truth.linear_acceleration, float), float(truth.time), math.sqrt(max(elapsed, 0.0)),
                            np.asarray(draws, float), self._gyro_bias, self._accel_bias, self._imu_constants, mounted, output,
                            tilted, values)
        return ImuReading(values[:4], values[4:7], values[7:], truth.time + jitter)


@compiled
def _measure_imu_kernel(
    quaternion: np.ndarray, gyro_true: np.ndarray, accel_true: np.ndarray, time: float, walk: float, draws: np.ndarray,
    gyro_bias: np.ndarray, accel_bias: np.ndarray, constants: np.ndarray, mounted: bool, output: bool, tilted: bool,
    values: np.ndarray,
) -> None:
    """One IMU sample from the truth into ``values`` (quaternion xyzw, gyro, accelerometer): the
    IMU's actual frame rotated in its nominal one (``mounted``: ``constants[0:9]``, its quaternion
    ``[9:13]``), the biases random-walked in place by ``walk`` = sqrt(elapsed s) times the walk
    densities, white noise, saturation at the ranges, and the orientation output's errors (``tilted``:
    a world-frame tilt ``[13:16]`` and a heading drifting at ``[16]`` rad/s over ``time``; its noise
    as a small body-frame rotation); without an ``output`` the quaternion is NaN. ``draws``: 15
    standard normals (gyro, gyro walk, accel, accel walk, orientation)."""
    c = constants
    qx, qy, qz, qw = quaternion[0], quaternion[1], quaternion[2], quaternion[3]
    g0, g1, g2 = gyro_true[0], gyro_true[1], gyro_true[2]
    a0, a1, a2 = accel_true[0], accel_true[1], accel_true[2]
    if mounted:  # q * mounting; the rates and the specific force in the actual frame (mounting^T v)
        bx, by, bz, bw = c[9], c[10], c[11], c[12]
        qx, qy, qz, qw = (qw * bx + qx * bw + qy * bz - qz * by, qw * by - qx * bz + qy * bw + qz * bx,
                          qw * bz + qx * by - qy * bx + qz * bw, qw * bw - qx * bx - qy * by - qz * bz)
        g0, g1, g2 = c[0] * g0 + c[3] * g1 + c[6] * g2, c[1] * g0 + c[4] * g1 + c[7] * g2, c[2] * g0 + c[5] * g1 + c[8] * g2
        a0, a1, a2 = c[0] * a0 + c[3] * a1 + c[6] * a2, c[1] * a0 + c[4] * a1 + c[7] * a2, c[2] * a0 + c[5] * a1 + c[8] * a2
    if c[17]:
        k = c[17] * walk
        for i in range(3):
            gyro_bias[i] = gyro_bias[i] + k * draws[3 + i]
    if c[18]:
        k = c[18] * walk
        for i in range(3):
            accel_bias[i] = accel_bias[i] + k * draws[9 + i]
    sg, sa, gr, ar = c[19], c[20], c[21], c[22]
    gyro = (g0 + gyro_bias[0] + sg * draws[0], g1 + gyro_bias[1] + sg * draws[1], g2 + gyro_bias[2] + sg * draws[2])
    accel = (a0 + accel_bias[0] + sa * draws[6], a1 + accel_bias[1] + sa * draws[7], a2 + accel_bias[2] + sa * draws[8])
    for i in range(3):
        values[4 + i] = min(max(gyro[i], -gr), gr) if gr < math.inf else gyro[i]
        values[7 + i] = min(max(accel[i], -ar), ar) if ar < math.inf else accel[i]
    if not output:
        for i in range(4):
            values[i] = math.nan
        return
    if tilted:  # world-frame error: constant tilt, heading drifting with time; error * q
        bx, by, bz, bw = _rotation_quaternion(c[13], c[14], c[15] + c[16] * time)
        qx, qy, qz, qw = (bw * qx + bx * qw + by * qz - bz * qy, bw * qy - bx * qz + by * qw + bz * qx,
                          bw * qz + bx * qy - by * qx + bz * qw, bw * qw - bx * qx - by * qy - bz * qz)
    o = c[23]
    if o:
        bx, by, bz, bw = _rotation_quaternion(o * draws[12], o * draws[13], o * draws[14])
        qx, qy, qz, qw = (qw * bx + qx * bw + qy * bz - qz * by, qw * by - qx * bz + qy * bw + qz * bx,
                          qw * bz + qx * by - qy * bx + qz * bw, qw * bw - qx * bx - qy * by - qz * bz)
    values[0], values[1], values[2], values[3] = qx, qy, qz, qw


@compiled
def _measure_joints(
    draws: np.ndarray, noise: np.ndarray, positions: np.ndarray, bias: np.ndarray, biased: bool, resolution: float,
    velocities: np.ndarray, efforts: np.ndarray, out: np.ndarray,
) -> None:
    """The joints' sample into ``out`` (3, n): positions (plus their ``bias`` when ``biased``) plus
    noise, quantized to the encoder's ``resolution`` (round half to even; 0: none), velocities and
    efforts plus noise; the noise is ``noise`` (3, n: the stds) times the draws after the IMU's 15."""
    n = positions.shape[0]
    for j in range(n):
        value = positions[j] + bias[j] if biased else positions[j]
        value = value + noise[0, j] * draws[15 + j]
        if resolution > 0:
            value = np.rint(value / resolution) * resolution
        out[0, j] = value
        out[1, j] = velocities[j] + noise[1, j] * draws[15 + n + j]
        out[2, j] = efforts[j] + noise[2, j] * draws[15 + 2 * n + j]


@compiled
def _rotation_quaternion(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """The unit quaternion ``(x, y, z, w)`` (``w >= 0`` for angles up to pi) of the rotation vector ``(x, y, z)``."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle == 0.0:
        return (0.0, 0.0, 0.0, 1.0)
    half = 0.5 * angle
    k = math.sin(half) / angle
    return (k * x, k * y, k * z, math.cos(half))


class NoisyRobot(RobotWrapper):
    """A :class:`Robot` reporting what a real robot measures, with noise and latency; see the module doc.

    ``robot`` is the wrapped robot, the ground truth: step and reset the simulation through it, and
    read it to evaluate an estimator. A wrapped robot whose time goes backwards (a reset) restarts
    the latency buffers; biases persist, as they would across a controller restart.
    """

    def __init__(self, robot: Robot, config: SensorNoiseConfig | None = None, rng: np.random.Generator | None = None) -> None:
        if rng is None:
            raise ValueError("NoisyRobot needs a seeded numpy.random.Generator (rng=np.random.default_rng(seed))")
        super().__init__(robot)
        self.config = config if config is not None else SensorNoiseConfig()
        self.sensors = SensorModel(robot, self.config.errors(rng), rng)

    # --- measured ---------------------------------------------------------------------------
    def imu(self) -> ImuReading:
        return self.sensors.imu()

    def joint_positions(self) -> np.ndarray:
        return self.sensors.joint_positions()

    def joint_velocities(self) -> np.ndarray:
        return self.sensors.joint_velocities()

    def joint_efforts(self) -> np.ndarray:
        return self.sensors.joint_efforts()

    # --- not measured on hardware -------------------------------------------------------------
    def base_state(self) -> BaseState:
        raise NotMeasuredError(
            "a real robot does not measure its base state: estimate it (giwbc.estimation.estimator.StateEstimator, "
            "or EstimatedRobot), or read noisy.robot.base_state() to evaluate"
        )

    def generalized_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joints only on a fixed base; a floating base needs the base state (not measured)."""
        return Robot.generalized_state(self)

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        raise NotMeasuredError(f"link poses need the base pose, which a real robot does not measure (link {link!r})")

    def contact_wrench(self, link: str) -> ContactWrench:
        raise NotMeasuredError(f"this robot has no force/torque sensor at {link!r}: estimate contacts from joint efforts")
