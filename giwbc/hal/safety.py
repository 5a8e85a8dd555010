"""The safety supervisor: what stops the robot, and how.

:class:`SafetySupervisor` checks one control cycle's measurements (a
:class:`~giwbc.hal.can_robot.CycleReport` plus joint state and IMU) against :class:`SafetyConfig`
and returns the :class:`Fault` s it finds: missing replies for N cycles, corrupt frames on a bus,
joints beyond their soft limits, velocity or torque beyond limits, base tilt beyond the fall
threshold (from the IMU's orientation output or, for an IMU without one, from its gyro and
accelerometer, see :meth:`SafetySupervisor.imu_tilt`), motor error codes, a motor that left motor mode (Damiao state 0), over-temperature, a
silent IMU, a bus whose driver refuses every frame (bus-off) or raises what no CAN driver should
(a driver bug). The runtime adds the faults it sees itself (non-finite policy or controller
output, controller exceptions and fallbacks, signals, ``KeyboardInterrupt``, task termination), and
its watchdog the loop that stopped producing cycles.

Any fault leads to the same safe stop, run by the runtime: damping (``kp = 0``, ``kd`` = damping
gain, ``tau_ff = 0``, see :func:`damping_command`) from the next exchange on (within two control
cycles of the detection), held for ``damping_time``, then motors off (exit motor mode), with the
cause logged. :class:`SignalWatch` turns SIGINT/SIGTERM into such a stop: it only records the
signal (installed and restored by the runtime, never at import); the control loop polls it
through the interpreter's wake-up fd, so a signal is seen at the next cycle whichever thread runs
the loop.
"""

from __future__ import annotations

import enum
import math
import signal
import socket
import threading
from dataclasses import dataclass, field
from types import FrameType
from typing import TYPE_CHECKING, Any

import can
import numpy as np

from giwbc.estimation.orientation import OrientationFilter
from giwbc.hal.kernels import quiet_joints, warm_up_quiet_joints
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
    MOTOR_DISABLED = "motor_disabled"  # a motor left motor mode (e.g. an exit frame from another node)
    BUS_OFF = "bus_off"  # a bus's driver refuses every frame (bus-off, interface down)
    DRIVER_ERROR = "driver_error"  # a bus driver raised what no CAN driver should (a driver bug)
    OVER_TEMPERATURE = "over_temperature"
    IMU = "imu"
    TIMING = "timing"
    NONFINITE_POLICY = "nonfinite_policy"
    NONFINITE_COMMAND = "nonfinite_command"
    POLICY_ERROR = "policy_error"
    CONTROLLER_ERROR = "controller_error"
    CONTROLLER_FAILED = "controller_failed"  # the controller fell back (infeasible QP, invalid state)
    TASK_TERMINATED = "task_terminated"
    SIGNAL = "signal"
    INTERRUPTED = "interrupted"  # KeyboardInterrupt raised inside the loop
    WATCHDOG = "watchdog"  # the loop stopped producing cycles (or its stop overran): the watchdog stopped the motors
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
    gravity_tilt_gain: float = 0.5  # 1/s: pull of the gravity direction on the gyro-propagated tilt (IMU without orientation output)
    max_temperature: float = 80.0  # °C, below the firmware's own trip
    imu_timeout_cycles: int = 10  # cycles without a fresh IMU sample
    max_stall: float = 0.1  # s a control cycle may start after its deadline (a stalled loop)
    damping_kd_scale: float = 1.0  # damping gain = this x the description's kd
    damping_time: float = 1.0  # s of damping before motors off
    bus_off_cycles: int = 2  # consecutive cycles in which a bus's driver refused every frame
    watchdog_periods: int = 50  # control periods (wall clock; unpaced runs: at least 1 s) without a cycle before the watchdog stops the motors
    stop_margin: float = 1.0  # s (wall clock) a safe stop may overrun its nominal length before the watchdog takes over
    start_limit_tolerance: float = 0.1  # rad a joint may read beyond its limits before start (resting on a stop)

    def __post_init__(self) -> None:
        for name in ("max_missing_cycles", "max_corrupt_frames", "corrupt_window", "torque_cycles", "imu_timeout_cycles",
                     "bus_off_cycles", "watchdog_periods"):  # fmt: skip
            if getattr(self, name) < 1:
                raise ValueError(f"safety {name} must be >= 1")
        if not (self.max_tilt > 0 and self.damping_time >= 0 and self.damping_kd_scale >= 0 and self.gravity_tilt_gain > 0):
            raise ValueError("safety max_tilt and gravity_tilt_gain must be > 0, damping_time and damping_kd_scale >= 0")
        if not self.stop_margin > 0:
            raise ValueError(f"safety stop_margin must be > 0, got {self.stop_margin}")


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
        self._bus_down = np.zeros(self._corrupt.shape[1], dtype=np.int64)
        self._down_any = False  # some bus refused every frame lately (its count must go on or reset)
        self.checks = 0
        # The tilt of an IMU without orientation output: gyro-propagated, pulled toward gravity, the gyro
        # bias learnt slowly (its integral runs within 10 degrees: a cheap gyro's turn-on bias lags the tilt by ~6).
        self._tilt_filter = OrientationFilter(orientation_gain=0.0, accel_gain=c.gravity_tilt_gain, bias_gain=0.0,
                                              integral_window=math.radians(10.0))  # fmt: skip
        self._tilt_time = -math.inf  # timestamp of the last IMU sample the tilt filter took
        self._no_status = np.ones(description.dofs, dtype=np.int64)  # (a report without motor states: nothing disabled)
        warm_up_quiet_joints(description.dofs, self._corrupt.shape[1])  # compiled here, never in a cycle

    def reset(self) -> None:
        self._bus_down[:] = 0
        self._down_any = False
        self._corrupt[:] = 0
        self._corrupt_total[:] = 0
        self._torque_over[:] = 0
        self._armed_limits[:] = False
        self._imu_stale = 0
        self._tilt_filter.initialized = False
        self._tilt_time = -math.inf

    def base_tilt(self, imu: ImuReading) -> float:
        """Angle (rad) between the base z axis and the vertical, from the IMU orientation."""
        return self._tilt_of(*(float(v) for v in imu.quaternion))

    def imu_tilt(self, imu: ImuReading) -> float:
        """The base tilt (rad) this sample shows: from the IMU's orientation output, or, for an IMU
        without one (an all-NaN quaternion, as :class:`~giwbc.robot.interface.ImuReading` reports
        it), from a complementary filter of its own: the gyro propagates the tilt (a robot tipping
        over its feet turns its accelerometer's reading with it, so gravity alone would not see the
        fall) and the accelerometer's gravity direction pulls it back at ``gravity_tilt_gain``
        while the specific force is near 1 g. Each new sample (by timestamp) is taken once; NaN
        when the sample is not finite."""
        quaternion = imu.quaternion
        x, y, z, w = floats = np.asarray(quaternion, float).tolist()
        if not math.isnan(x) or not all(map(math.isnan, floats)):  # (one float test on the quiet path)
            return self._tilt_of(x, y, z, w)
        gyro, accel = np.asarray(imu.angular_velocity, float), np.asarray(imu.linear_acceleration, float)
        if not (np.isfinite(gyro).all() and np.isfinite(accel).all() and math.isfinite(imu.time)):
            return math.nan
        f, now = self._tilt_filter, float(imu.time)
        if not f.initialized:
            if not f.initialize(None, accel):  # no gravity to start from (free fall): vertical unknown
                return math.nan
            self._tilt_time = now
        elif now > self._tilt_time:
            f.update(gyro, min(now - self._tilt_time, 0.1), None, accel)
            self._tilt_time = now
        return self._tilt_of(*f.quaternion_floats)

    def _tilt_of(self, x: float, y: float, z: float, w: float) -> float:
        """Angle (rad) between the base z axis and the vertical, for the IMU orientation ``(x, y, z, w)``."""
        r = self._base_z_in_imu  # the base z axis in IMU coordinates
        # Last row of the IMU's rotation matrix (world z in IMU coordinates) dotted with it.
        cos_tilt = 2 * (x * z - y * w) * r[0] + 2 * (y * z + x * w) * r[1] + (1 - 2 * (x * x + y * y)) * r[2]
        if cos_tilt != cos_tilt:  # NaN (a broken orientation output): min/max below would clamp it to level
            return math.nan
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

        status = report.status
        if quiet_joints(report.error_code, self._no_status if status is None else status, status is not None, report.temperature,
                        c.max_temperature, report.corrupt, self._corrupt_total, report.stale, c.max_missing_cycles, q, self.soft_lower,
                        self.soft_upper, self._armed_limits, report.missing, dq, self.velocity_limit, tau, self.torque_limit,
                        self._torque_over):  # fmt: skip
            # The quiet path (one compiled call): no joint or frame to look at; the buses' drivers and the IMU remain.
            if report.bus_errors is not None:
                self._bus_faults(report, add)
            self._imu_faults(report, imu, add)
            return faults

        error = report.error_code > 0
        if np.count_nonzero(error):
            codes = ", ".join(f"{names[j]}={int(report.error_code[j])}" for j in np.flatnonzero(error))
            add(FaultKind.MOTOR_ERROR, f"motor error code(s): {codes}", error)
        if report.status is not None and np.count_nonzero(report.status) < report.status.size:  # some state 0 (quiet path: one reduction)
            disabled = (report.status == 0) & ~report.missing  # Damiao state 0: out of motor mode
            if np.count_nonzero(disabled):
                which = ", ".join(names[j] for j in np.flatnonzero(disabled))
                add(FaultKind.MOTOR_DISABLED, f"motor(s) left motor mode (reply state 'disabled'): {which}", disabled)
        if report.bus_errors is not None:
            self._bus_faults(report, add)
        hot = report.temperature > c.max_temperature  # NaN (not reported) compares False
        if np.count_nonzero(hot):  # (count_nonzero: a quarter of .any()'s cost on these small arrays)
            temps = ", ".join(f"{names[j]}={report.temperature[j]:.0f}°C" for j in np.flatnonzero(hot))
            add(FaultKind.OVER_TEMPERATURE, f"above {c.max_temperature:g}°C: {temps}", hot)

        slot = cycle % c.corrupt_window
        if np.count_nonzero(report.corrupt) or np.count_nonzero(self._corrupt_total):
            row = np.zeros(self._corrupt.shape[1], dtype=np.int64)
            row[: len(report.corrupt)] = report.corrupt
            self._corrupt_total += row - self._corrupt[slot]
            self._corrupt[slot] = row
            bad_bus = self._corrupt_total >= c.max_corrupt_frames
            if np.count_nonzero(bad_bus):
                which = ", ".join(f"{self.bus_names[b]} ({self._corrupt_total[b]})" for b in np.flatnonzero(bad_bus))
                add(FaultKind.CORRUPT_FRAMES, f"corrupt frames in the last {c.corrupt_window} cycles on {which}")
        silent = report.stale >= c.max_missing_cycles
        if np.count_nonzero(silent):
            which = ", ".join(f"{names[j]} ({int(report.stale[j])})" for j in np.flatnonzero(silent))
            extra = f"; {report.late} late frame(s) this cycle" if report.late else ""
            add(FaultKind.MISSING_REPLIES, f"no valid reply for >= {c.max_missing_cycles} cycles: {which}{extra}", silent)

        self._imu_faults(report, imu, add)

        inside = (q >= self.soft_lower) & (q <= self.soft_upper)
        self._armed_limits |= inside
        beyond = self._armed_limits > (inside | report.missing)  # armed, outside and measured (bools: a > b is a & ~b)
        if np.count_nonzero(beyond):
            which = ", ".join(
                f"{names[j]}={q[j]:.3f} not in [{self.soft_lower[j]:.3f}, {self.soft_upper[j]:.3f}]" for j in np.flatnonzero(beyond)
            )
            add(FaultKind.JOINT_LIMIT, f"beyond soft limits: {which}", beyond)
        fast = np.abs(dq) > self.velocity_limit
        if np.count_nonzero(fast):
            which = ", ".join(f"{names[j]}={dq[j]:.1f} rad/s" for j in np.flatnonzero(fast))
            add(FaultKind.VELOCITY_LIMIT, f"beyond velocity limits: {which}", fast)
        over = np.abs(tau) > self.torque_limit
        if np.count_nonzero(over) or np.count_nonzero(self._torque_over):
            self._torque_over = np.where(over, self._torque_over + 1, 0)
            strong = self._torque_over >= c.torque_cycles
            if np.count_nonzero(strong):
                which = ", ".join(f"{names[j]}={tau[j]:.1f} N m" for j in np.flatnonzero(strong))
                add(FaultKind.TORQUE_LIMIT, f"beyond torque limits for {c.torque_cycles} cycles: {which}", strong)
        return faults


    def _imu_faults(self, report: CycleReport, imu: ImuReading | None, add: Any) -> None:
        """A stale, broken or tilted IMU sample (the IMU's part of :meth:`check`, in its place)."""
        c = self.config
        self._imu_stale = 0 if imu is not None and report.imu_fresh else self._imu_stale + 1
        if self._imu_stale >= c.imu_timeout_cycles:
            add(FaultKind.IMU, f"no fresh IMU sample for {self._imu_stale} cycles")
        elif imu is not None:
            tilt = self.imu_tilt(imu)
            if not math.isfinite(tilt) or not all(math.isfinite(v) for v in imu.angular_velocity):
                add(FaultKind.IMU, f"IMU sample is not finite: {imu}")
            elif tilt > c.max_tilt:
                add(FaultKind.FALL, f"base tilt {math.degrees(tilt):.1f}° beyond {math.degrees(c.max_tilt):.1f}°")

    def _bus_faults(self, report: CycleReport, add: Any) -> None:
        """Bus-off (every frame of a bus refused by its driver for ``bus_off_cycles``) and driver
        bugs (a driver raising what no CAN driver should: at once)."""
        errors, sent = report.bus_errors, report.bus_sent
        assert errors is not None and sent is not None
        causes = report.driver_errors or ()
        if not (np.count_nonzero(errors) or self._down_any or any(causes)):  # the quiet path: no driver error anywhere
            return
        refused = (errors > 0) & (sent == 0)
        self._bus_down[: len(refused)] = np.where(refused, self._bus_down[: len(refused)] + 1, 0)
        self._down_any = bool(self._bus_down.any())
        bugs = [b for b, e in enumerate(causes) if e is not None and not isinstance(e, (can.CanError, OSError))]
        if bugs:
            which = "; ".join(f"{self.bus_names[b]}: {type(causes[b]).__name__}: {causes[b]}" for b in bugs)
            add(FaultKind.DRIVER_ERROR, f"bus driver raised: {which}")
        down = [b for b in np.flatnonzero(self._bus_down >= self.config.bus_off_cycles).tolist() if b not in bugs]
        if down:
            def cause(b: int) -> str:
                e = causes[b] if b < len(causes) else None
                return f" ({type(e).__name__}: {e})" if e is not None else ""

            which = "; ".join(f"{self.bus_names[b]}{cause(b)}" for b in down)
            add(FaultKind.BUS_OFF, f"bus-off: the driver refused every frame for {int(self._bus_down[down].min())} cycles on {which}")


@dataclass
class SignalWatch:
    """Records SIGINT/SIGTERM/SIGHUP/SIGQUIT instead of raising (or dying), between :meth:`install`
    and :meth:`restore`.

    Handlers can only be installed from the main thread: elsewhere :attr:`installed` stays False
    and the caller relies on :meth:`trigger` (the same path a handler takes). Python runs a
    handler in the main thread only when that thread gets the interpreter; the control loop may
    run in another one, so :meth:`poll` also reads the interpreter's wake-up fd (written by the C
    signal handler at delivery): the loop sees a signal at its next cycle, whatever runs where.
    """

    # SIGHUP too: an operator's terminal or ssh session that goes away must stop the robot, not kill
    # the process with the motors on. (SIGKILL cannot be caught: the motors' own timeout is left.)
    signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)
    received: int | None = None
    installed: bool = False
    _previous: dict[int, Any] = field(default_factory=dict)
    _wakeup: socket.socket | None = None
    _wakeup_write: socket.socket | None = None
    _previous_fd: int = -1

    def install(self) -> SignalWatch:
        if self.installed or threading.current_thread() is not threading.main_thread():
            return self
        for sig in self.signals:
            self._previous[sig] = signal.signal(sig, self._handler)
        read, write = socket.socketpair()
        read.setblocking(False)
        write.setblocking(False)
        try:
            self._previous_fd = signal.set_wakeup_fd(write.fileno(), warn_on_full_buffer=False)
            self._wakeup, self._wakeup_write = read, write
        except (ValueError, OSError):  # pragma: no cover - main thread checked above
            read.close()
            write.close()
        self.installed = True
        return self

    def restore(self) -> None:
        if not self.installed or threading.current_thread() is not threading.main_thread():
            return
        for sig, previous in self._previous.items():
            signal.signal(sig, previous)
        self._previous.clear()
        if self._wakeup is not None:
            try:
                signal.set_wakeup_fd(self._previous_fd)
            except (ValueError, OSError):  # pragma: no cover
                pass
            for sock in (self._wakeup, self._wakeup_write):
                if sock is not None:
                    sock.close()
            self._wakeup = self._wakeup_write = None
        self.installed = False

    def poll(self) -> int | None:
        """The first watched signal delivered so far (also read from the wake-up fd, see the class
        docstring), or None. Costs one non-blocking read."""
        if self.received is None and self._wakeup is not None:
            try:
                data = self._wakeup.recv(256)
            except OSError:  # nothing waiting (BlockingIOError), or closed
                data = b""
            for signum in data:
                if signum in self.signals:
                    self.trigger(signum)
                    break
        return self.received

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
