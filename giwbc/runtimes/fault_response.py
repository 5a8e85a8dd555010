"""How the real-time runtime meets a fault: record it (the first one switches the command to
damping at once), abort a step, and the watchdog's way out when the loop is stuck
(:meth:`FaultResponse.take_over`). A mixin of :class:`~giwbc.runtimes.realtime.RealtimeRuntime`:
its methods read and change the runtime's fault, phase, robot and log."""

from __future__ import annotations

from typing import Any

import numpy as np

from giwbc.hal.can_robot import CanRobot, CycleReport
from giwbc.hal.safety import Fault, FaultKind, SafetySupervisor
from giwbc.runtimes.phases import Phase
from giwbc.runtimes.watchdog import EmergencyStop


class LoopAbandoned(BaseException):
    """Raised in the loop's thread once the watchdog took over: the loop must not touch the motors."""


class FaultResponse:
    """Fault recording and the stops it triggers (see the module docstring)."""

    def _abort(self, kind: FaultKind, message: str) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """A fault found between cycles: record it, stop safely, return a terminal step."""
        self._fail(kind, message)
        self._safe_stop()
        return self._last_observation(), 0.0, True, False, self._info()

    def _abort_on(self, error: BaseException, kind: FaultKind, what: str) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """:meth:`_abort` for an exception (see :meth:`_fail_on`)."""
        self._fail_on(error, kind, what)
        self._safe_stop()
        return self._last_observation(), 0.0, True, False, self._info()

    # --- faults -----------------------------------------------------------------------------
    def _fail(self, kind: FaultKind, message: str, joints: tuple[str, ...] = ()) -> None:
        """Record a fault (at the last exchange's cycle); the first one switches the command to
        damping at once, so the next exchange sends it."""
        fault = Fault(kind, message, max(0, self.robot.cycle - 1), self._now, tuple(joints))
        with self._fault_lock:  # the watchdog's thread records faults too
            if self.fault is None:
                try:
                    self.robot.set_joint_impedance(self.damping)  # first: the next exchange sends it
                except Exception:  # noqa: BLE001 - the damping command is valid by construction
                    pass
                self.fault = fault
                self.armed = False
                self._stop_at = self._now + self.safety.damping_time
            self._record(fault)

    def _fail_on(self, error: BaseException, kind: FaultKind, what: str) -> None:
        """Record an exception as a fault: ``KeyboardInterrupt`` as :attr:`FaultKind.INTERRUPTED`,
        ``SystemExit`` and the like as internal errors, anything else as ``kind``."""
        if isinstance(error, KeyboardInterrupt):
            self._fail(FaultKind.INTERRUPTED, f"KeyboardInterrupt raised inside the loop ({what})")
        elif not isinstance(error, Exception):
            self._fail(FaultKind.INTERNAL, f"{what}: {describe(error)}")
        else:
            self._fail(kind, f"{what}: {describe(error)}")

    def _controller_failure(self) -> str | None:
        """Why the task's last controller tick fell back (infeasible QP, ...), or None."""
        check = getattr(self.task, "controller_failure", None)
        if check is None:
            return None
        try:
            return check()
        except Exception as error:  # noqa: BLE001
            return f"controller status unreadable: {describe(error)}"

    def _driver_error_event(self, report: CycleReport) -> None:
        """Log a bus driver's first exception (per bus): the cause a bus-off or a missing reply needs."""
        names = self.supervisor.bus_names
        for b, error in enumerate(report.driver_errors):
            if error is not None and b not in self._driver_errors_seen:
                self._driver_errors_seen.add(b)
                sent = None if report.bus_sent is None else int(report.bus_sent[b])
                errors = None if report.bus_errors is None else int(report.bus_errors[b])
                self._event("driver_error", {"bus": names[b] if b < len(names) else b, "error": describe(error),
                                             "sent": sent, "errors": errors})  # fmt: skip

    # --- the watchdog's way out ---------------------------------------------------------------
    def take_over(self, reason: str) -> bool:
        """Called by the watchdog from its own thread: abandon the loop and stop the motors without
        it (damping for ``damping_time``, then exit motor mode; see the module docstring).
        Returns False when there was nothing to do (motors already off, already taken over)."""
        with self._fault_lock:
            if self.phase in (Phase.IDLE, Phase.OFF) or self._abandoned:
                return False
            self._abandoned = True
        self._fail(FaultKind.WATCHDOG, reason)
        # A loop still cycling (a stop that overran) finishes its exchange first; one stuck in it does not.
        held = self._exchange_lock.acquire(timeout=2 * self.period)
        try:
            own = getattr(self.robot, "emergency_stop", None)  # a robot with a stop of its own (DDS: giwbc.hal.dds.robot)
            stop = own(self.damping) if own is not None else EmergencyStop(self.robot, self.damping)
            self.emergency = stop.run(self._now, self.period, self.safety.damping_time, self.startup.exit_attempts,
                                      realtime=self.clock.realtime)  # fmt: skip
            self._now = self.emergency["time"]
        except Exception as error:  # noqa: BLE001 - whatever happens, the loop stays abandoned
            self.emergency = {"error": describe(error)}
        finally:
            if held:
                self._exchange_lock.release()
        self.phase = Phase.OFF
        self.phase_times.setdefault(Phase.OFF, self._now)
        self._event("watchdog", {"reason": reason, **{k: v for k, v in (self.emergency or {}).items() if k != "time"}})
        self._event("motors_off", {"fault": None if self.fault is None else str(self.fault), "by": "watchdog"})
        self.taken_over.set()
        self._wake.set()
        return True

    def _record(self, fault: Fault) -> None:
        if any(f.kind is fault.kind for f in self.faults):
            return  # one record per kind: a lost motor would otherwise be reported every cycle
        self.faults.append(fault)
        if self.log is not None and self._log_lock.acquire(timeout=0.5):
            try:
                self.log.fault(fault)
            except Exception:  # noqa: BLE001 - logging must not stop the stop
                pass
            finally:
                self._log_lock.release()


def robot_faults(supervisor: SafetySupervisor, robot: CanRobot, report: CycleReport) -> list[Fault]:
    """The supervisor's faults for the robot's current measurements."""
    q, dq, tau = robot.measured
    return supervisor.check(report, q, dq, tau, robot.latest_imu)


def describe(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"


__all__ = ["FaultResponse", "LoopAbandoned", "describe", "robot_faults"]
