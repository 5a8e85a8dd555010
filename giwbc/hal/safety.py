"""The safety supervisor: what stops the robot, and how.

:class:`SafetySupervisor` checks one control cycle's measurements (a
:class:`~giwbc.hal.can_robot.CycleReport` plus joint state and IMU) against :class:`SafetyConfig`
and returns the :class:`Fault` s it finds: missing replies for N cycles, corrupt frames on a bus,
joints beyond their soft limits, velocity or torque beyond limits, base tilt beyond the fall
threshold, motor error codes, over-temperature, a silent IMU. The runtime adds the faults it sees
itself (non-finite policy or controller output, controller exceptions, signals, task termination).

Any fault leads to the same safe stop, run by the runtime: damping (``kp = 0``, ``kd`` = damping
gain, ``tau_ff = 0``, see :func:`damping_command`) from the next exchange on (within two control
cycles of the detection), held for ``damping_time``, then motors off (exit motor mode), with the
cause logged. :class:`SignalWatch` turns SIGINT/SIGTERM into such a stop: it only records the
signal (installed and restored by the runtime, never at import).
"""

from __future__ import annotations

import enum
import math
import signal
import threading
from dataclasses import dataclass, field
from types import FrameType
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.robot.interface import ImpedanceCommand, ImuReading

if TYPE_CHECKING:
    from giwbc.hal.can_robot import CycleReport
    from giwbc.robot.description import RobotDescription


class FaultKind(str, enum.Enum):
    """Why the robot was stopped."""

    MISSING_REPLIES = "missing_replies"
    CORRUPT_FRAMES = "corrupt_frames"
    JOINT_LIMIT = "joint_limit"
    VELOCITY_LIMIT = "velocity_limit"
    TORQUE_LIMIT = "torque_limit"
    FALL = "fall"
    MOTOR_ERROR = "motor_error"
    OVER_TEMPERATURE = "over_temperature"
    IMU = "imu"
    TIMING = "timing"
    NONFINITE_POLICY = "nonfinite_policy"
    NONFINITE_COMMAND = "nonfinite_command"
    POLICY_ERROR = "policy_error"
    CONTROLLER_ERROR = "controller_error"
    TASK_TERMINATED = "task_terminated"
    SIGNAL = "signal"
    STARTUP = "startup"
    INTERNAL = "internal_error"


@dataclass(frozen=True)
class Fault:
    """One cause of a stop: what, when (cycle, robot time) and which joints."""

    kind: FaultKind
    message: str
    cycle: int
    time: float
    joints: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind.value, "message": self.message, "cycle": self.cycle, "time": self.time, "joints": list(self.joints)}

    def __str__(self) -> str:
        return f"{self.kind.value} at cycle {self.cycle} (t = {self.time:.3f} s): {self.message}"


@dataclass(frozen=True)
class SafetyConfig:
    """Thresholds of the supervisor and the safe stop.

    Joint soft limits are the description's limits moved inward by ``soft_limit_margin`` rad; a
    joint is only checked once it has been inside them (a robot may start resting on a stop).
    """

    max_missing_cycles: int = 3  # consecutive cycles without a valid reply from one motor
    max_corrupt_frames: int = 3  # undecodable frames on one bus within corrupt_window cycles
    corrupt_window: int = 50
    soft_limit_margin: float = 0.02  # rad
    velocity_scale: float = 1.0  # x the description's velocity limits
    torque_scale: float = 1.1  # x the effort limits (replies are quantized, saturation reads at the limit)
    torque_cycles: int = 3  # consecutive cycles beyond the torque limit
    max_tilt: float = 0.7  # rad between the base z axis and the vertical
    max_temperature: float = 80.0  # °C, below the firmware's own trip
    imu_timeout_cycles: int = 10  # cycles without a fresh IMU sample
    max_stall: float = 0.1  # s a control cycle may start after its deadline (a stalled loop)
    damping_kd_scale: float = 1.0  # damping gain = this x the description's kd
    damping_time: float = 1.0  # s of damping before motors off

    def __post_init__(self) -> None:
        for name in ("max_missing_cycles", "max_corrupt_frames", "corrupt_window", "torque_cycles", "imu_timeout_cycles"):
            if getattr(self, name) < 1:
                raise ValueError(f"safety {name} must be >= 1")
        if not (self.max_tilt > 0 and self.damping_time >= 0 and self.damping_kd_scale >= 0):
            raise ValueError("safety max_tilt must be > 0, damping_time and damping_kd_scale >= 0")


def damping_command(description: RobotDescription, config: SafetyConfig) -> ImpedanceCommand:
    """The safe state: ``kp = 0``, ``kd = damping_kd_scale * kd``, ``tau_ff = 0``."""
    return ImpedanceCommand.damping(description.dofs, config.damping_kd_scale * description.kd)


class SafetySupervisor:
    """Checks each cycle's measurements (see the module docstring); keeps the per-joint history."""

    def __init__(self, description: RobotDescription, config: SafetyConfig | None = None, *, n_buses: int = 1,
                 bus_names: tuple[str, ...] = ()) -> None:  # fmt: skip
        self.description = description
        self.config = c = config or SafetyConfig()
        self.names = description.joint_names
        lower, upper = description.position_limits
        self.soft_lower = lower + c.soft_limit_margin
        self.soft_upper = upper - c.soft_limit_margin
        self.velocity_limit = c.velocity_scale * description.velocity_limits
        self.torque_limit = np.where(description.effort_limits > 0, c.torque_scale * description.effort_limits, np.inf)
        self._imu_in_base = np.array(description.imu_in_base.rotation)
        self._base_z_in_imu = self._imu_in_base.T[:, 2].tolist()
        self.bus_names = bus_names or tuple(f"bus{b}" for b in range(n_buses))
        self._corrupt = np.zeros((c.corrupt_window, max(1, len(self.bus_names))), dtype=np.int64)
        self._corrupt_total = np.zeros(self._corrupt.shape[1], dtype=np.int64)
        self._torque_over = np.zeros(description.dofs, dtype=np.int64)
        self._armed_limits = np.zeros(description.dofs, dtype=bool)
        self._imu_stale = 0
        self.checks = 0

    def reset(self) -> None:
        self._corrupt[:] = 0
        self._corrupt_total[:] = 0
        self._torque_over[:] = 0
        self._armed_limits[:] = False
        self._imu_stale = 0

    def base_tilt(self, imu: ImuReading) -> float:
        """Angle (rad) between the base z axis and the vertical, from the IMU orientation."""
        x, y, z, w = (float(v) for v in imu.quaternion)
        r = self._base_z_in_imu  # the base z axis in IMU coordinates
        # Last row of the IMU's rotation matrix (world z in IMU coordinates) dotted with it.
        cos_tilt = 2 * (x * z - y * w) * r[0] + 2 * (y * z + x * w) * r[1] + (1 - 2 * (x * x + y * y)) * r[2]
        return math.acos(max(-1.0, min(1.0, cos_tilt)))

    def check(
        self,
        report: CycleReport,
        q: np.ndarray,
        dq: np.ndarray,
        tau: np.ndarray,
        imu: ImuReading | None,
    ) -> list[Fault]:
        """Every fault of this cycle, most urgent first (empty when all is well).

        The quiet path (nothing wrong) costs a few vectorized comparisons; messages are only
        built for what is wrong."""
        c, names = self.config, self.names
        cycle, t = report.cycle, report.time
        faults: list[Fault] = []
        self.checks += 1

        def add(kind: FaultKind, message: str, mask: np.ndarray | None = None) -> None:
            joints = tuple(names[j] for j in np.flatnonzero(mask)) if mask is not None else ()
            faults.append(Fault(kind, message, cycle, t, joints))

        if report.error_code.max() > 0:
            error = report.error_code > 0
            codes = ", ".join(f"{names[j]}={int(report.error_code[j])}" for j in np.flatnonzero(error))
            add(FaultKind.MOTOR_ERROR, f"motor error code(s): {codes}", error)
        hot = report.temperature > c.max_temperature  # NaN (not reported) compares False
        if hot.any():
            temps = ", ".join(f"{names[j]}={report.temperature[j]:.0f}°C" for j in np.flatnonzero(hot))
            add(FaultKind.OVER_TEMPERATURE, f"above {c.max_temperature:g}°C: {temps}", hot)

        slot = cycle % c.corrupt_window
        if report.corrupt.any() or self._corrupt_total.any():
            row = np.zeros(self._corrupt.shape[1], dtype=np.int64)
            row[: len(report.corrupt)] = report.corrupt
            self._corrupt_total += row - self._corrupt[slot]
            self._corrupt[slot] = row
            bad_bus = self._corrupt_total >= c.max_corrupt_frames
            if bad_bus.any():
                which = ", ".join(f"{self.bus_names[b]} ({self._corrupt_total[b]})" for b in np.flatnonzero(bad_bus))
                add(FaultKind.CORRUPT_FRAMES, f"corrupt frames in the last {c.corrupt_window} cycles on {which}")
        if report.stale.max() >= c.max_missing_cycles:
            silent = report.stale >= c.max_missing_cycles
            which = ", ".join(f"{names[j]} ({int(report.stale[j])})" for j in np.flatnonzero(silent))
            extra = f"; {report.late} late frame(s) this cycle" if report.late else ""
            add(FaultKind.MISSING_REPLIES, f"no valid reply for >= {c.max_missing_cycles} cycles: {which}{extra}", silent)

        self._imu_stale = 0 if imu is not None and report.imu_fresh else self._imu_stale + 1
        if self._imu_stale >= c.imu_timeout_cycles:
            add(FaultKind.IMU, f"no fresh IMU sample for {self._imu_stale} cycles")
        elif imu is not None:
            tilt = self.base_tilt(imu)
            if not math.isfinite(tilt) or not all(math.isfinite(v) for v in imu.angular_velocity):
                add(FaultKind.IMU, f"IMU sample is not finite: {imu}")
            elif tilt > c.max_tilt:
                add(FaultKind.FALL, f"base tilt {math.degrees(tilt):.1f}° beyond {math.degrees(c.max_tilt):.1f}°")

        inside = (q >= self.soft_lower) & (q <= self.soft_upper)
        self._armed_limits |= inside
        beyond = self._armed_limits & ~inside & ~report.missing
        if beyond.any():
            which = ", ".join(
                f"{names[j]}={q[j]:.3f} not in [{self.soft_lower[j]:.3f}, {self.soft_upper[j]:.3f}]" for j in np.flatnonzero(beyond)
            )
            add(FaultKind.JOINT_LIMIT, f"beyond soft limits: {which}", beyond)
        fast = np.abs(dq) > self.velocity_limit
        if fast.any():
            which = ", ".join(f"{names[j]}={dq[j]:.1f} rad/s" for j in np.flatnonzero(fast))
            add(FaultKind.VELOCITY_LIMIT, f"beyond velocity limits: {which}", fast)
        over = np.abs(tau) > self.torque_limit
        if over.any() or self._torque_over.any():
            self._torque_over = np.where(over, self._torque_over + 1, 0)
            strong = self._torque_over >= c.torque_cycles
            if strong.any():
                which = ", ".join(f"{names[j]}={tau[j]:.1f} N m" for j in np.flatnonzero(strong))
                add(FaultKind.TORQUE_LIMIT, f"beyond torque limits for {c.torque_cycles} cycles: {which}", strong)
        return faults


@dataclass
class SignalWatch:
    """Records SIGINT/SIGTERM instead of raising, between :meth:`install` and :meth:`restore`.

    Outside the main thread handlers cannot be installed: :attr:`installed` stays False and the
    caller relies on :meth:`trigger` (the same path a handler takes).
    """

    signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)
    received: int | None = None
    installed: bool = False
    _previous: dict[int, Any] = field(default_factory=dict)

    def install(self) -> SignalWatch:
        if self.installed or threading.current_thread() is not threading.main_thread():
            return self
        for sig in self.signals:
            self._previous[sig] = signal.signal(sig, self._handler)
        self.installed = True
        return self

    def restore(self) -> None:
        if not self.installed:
            return
        for sig, previous in self._previous.items():
            signal.signal(sig, previous)
        self._previous.clear()
        self.installed = False

    def trigger(self, signum: int) -> None:
        """What the handler does: remember the first signal."""
        if self.received is None:
            self.received = int(signum)

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        self.trigger(signum)

    @property
    def name(self) -> str | None:
        return None if self.received is None else signal.Signals(self.received).name

    def __enter__(self) -> SignalWatch:
        return self.install()

    def __exit__(self, *exc: Any) -> None:
        self.restore()


__all__ = ["Fault", "FaultKind", "SafetyConfig", "SafetySupervisor", "SignalWatch", "damping_command"]
