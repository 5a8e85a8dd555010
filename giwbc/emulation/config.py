"""Settings and records of the actuator emulator: its configuration (firmware, thermal model,
faults, gantry) and what it counts and records."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from giwbc.emulation.faults import FaultInjection
from giwbc.emulation.thermal import ThermalModel
from giwbc.robot.noise import SensorNoiseConfig


@dataclass(frozen=True)
class Gantry:
    """A harness holding the base at its initial pose until ``until`` seconds (a spring-damper
    wrench on the base plus the robot's weight), as a robot hangs while its motors start."""

    until: float
    stiffness: float = 5000.0  # N/m
    damping: float = 200.0  # N s/m (explicit: keep damping * dt / mass of the base link well below 1)
    angular_stiffness: float = 300.0  # N m/rad
    angular_damping: float = 10.0  # N m s/rad


@dataclass(frozen=True)
class EmulatorConfig:
    """Firmware and simulation settings of :class:`ActuatorEmulator`."""

    watchdog_timeout: float = 0.05  # s without a frame before a motor in motor mode goes limp
    limp_kd: float = 0.0  # joint-side damping of a limp motor (0: zero torque, as Ben Katz firmware)
    thermal: ThermalModel = field(default_factory=ThermalModel)
    seed: int | None = 0
    initial_joint_positions: tuple[float, ...] | None = None  # default: the description's pose
    gantry: Gantry | None = None
    faults: tuple[FaultInjection, ...] = ()
    record: bool = False  # keep per-poll snapshots of what the motors apply (tests)
    record_truth: bool = True  # keep (time, base height, base tilt, base x, base y) after every physics advance
    # The IMU's errors (e.g. SensorNoiseConfig.profile("mems"): gyro + accelerometer only, turn-on
    # biases drawn from the seed, latency, dropouts); None: MuJoCo's exact IMU.
    imu: SensorNoiseConfig | None = None


@dataclass(frozen=True)
class AppliedSnapshot:
    """What the motors applied after one poll (joint side, description order)."""

    time: float
    mode: np.ndarray  # OFF / MOTOR per joint
    limp: np.ndarray  # no torque from a command (off, timed out, latched error, dead)
    kp: np.ndarray
    kd: np.ndarray
    tau_ff: np.ndarray
    q_ref: np.ndarray


@dataclass
class EmulatorCounters:
    """Per motor (plan order): frames heard, replies sent, and what faults did to replies."""

    frames: np.ndarray
    commands: np.ndarray  # impedance commands applied (in motor mode)
    specials: np.ndarray
    replies: np.ndarray
    dropped: np.ndarray
    delayed: np.ndarray
    corrupted: np.ndarray
    ignored: int = 0  # frames no configured motor accepts
    polls: int = 0
    physics_steps: int = 0

    @classmethod
    def zeros(cls, n: int) -> EmulatorCounters:
        z = lambda: np.zeros(n, dtype=np.int64)  # noqa: E731
        return cls(z(), z(), z(), z(), z(), z(), z())


__all__ = ["AppliedSnapshot", "EmulatorConfig", "EmulatorCounters", "Gantry"]
