"""The real-time runtime's phases (:class:`Phase`) and their sequencing (:class:`PhaseSequence`)::

    idle -> check (motors read without torque: refuse joints outside their limits)
         -> enable (enter motor mode) -> settle (damping) -> ramp (measured pose -> default pose)
         -> calibrate (joint-PD hold of the default pose, until the state estimator is ready)
         -> running (controller) -> shutdown (ramp to damping) -> damping -> off (exit motor mode)

Calibrate (only with a state estimator that calibrates): the estimator takes the IMU's gyro bias,
the base tilt and the accelerometer bias from a window of samples in which it *detects* a
standstill on both loaded feet (:mod:`giwbc.estimation.calibration`). The robot is only still on
both feet once the ramp holds the default pose (in damping it sags), so this is the first moment
it can; the controller, which reads the estimate, gets its first tick only once the estimator is
ready. No readiness within ``calibration_timeout``: a ``startup`` fault saying what the
standstill detector last saw. What it found is logged (event ``calibration``).

A fault at any point goes to damping for ``damping_time``, then off (:meth:`PhaseSequence._safe_stop`).
:class:`StartupConfig` holds the start-up and shutdown timing. Phase values are the strings the
run log records.
"""

from __future__ import annotations

import enum
import gc
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from giwbc.hal.can_robot import COMMAND, ENTER, EXIT, CycleReport
from giwbc.hal.safety import FaultKind
from giwbc.robot.interface import ImpedanceCommand
from giwbc.runtimes.ramps import PROFILES, cosine
from giwbc.runtimes.watchdog import LoopWatchdog

UNPACED_WATCHDOG = 1.0  # s: the watchdog's least timeout when the loop is not paced by the wall clock


class Phase(enum.StrEnum):
    """Where the runtime is in its life; the values are what the run log records."""

    IDLE = "idle"
    ENABLE = "enable"
    SETTLE = "settle"
    RAMP = "ramp"
    CALIBRATE = "calibrate"
    RUNNING = "running"
    SHUTDOWN = "shutdown"
    DAMPING = "damping"
    OFF = "off"


@dataclass(frozen=True)
class StartupConfig:
    """Start-up and shutdown timing (s)."""

    settle_time: float = 0.1  # damping after entering motor mode, reading the pose
    ramp_time: float = 2.0  # measured pose -> default pose
    ramp_profile: str = "minjerk"
    gain_ramp: float = 0.2  # fraction of the ramp over which kp, kd rise from the damping gains
    shutdown_time: float = 1.0  # last command -> damping at the end of a clean run
    off_delay: float = 0.5  # damping held before motors off after a clean run
    enable_attempts: int = 5  # cycles of enter-motor-mode frames before giving up (plus the robot's reply lag)
    exit_attempts: int = 3  # cycles of exit-motor-mode frames, fewer when every motor confirmed
    calibration_timeout: float = 15.0  # s of holding still for the state estimator's calibration before giving up

    def __post_init__(self) -> None:
        if self.ramp_profile not in PROFILES:
            raise ValueError(f"ramp_profile must be one of {list(PROFILES)}, got {self.ramp_profile!r}")
        times = {"settle_time": self.settle_time, "ramp_time": self.ramp_time, "gain_ramp": self.gain_ramp,
                 "shutdown_time": self.shutdown_time, "off_delay": self.off_delay}  # fmt: skip
        bad = {name: value for name, value in times.items() if not (math.isfinite(value) and value >= 0)}
        if bad or self.enable_attempts < 1 or self.exit_attempts < 1:
            raise ValueError(f"start-up times must be finite and >= 0, enable_attempts and exit_attempts >= 1; got {bad or ''}"
                             f"{'' if bad else f'enable_attempts={self.enable_attempts}, exit_attempts={self.exit_attempts}'}")  # fmt: skip
        if not (math.isfinite(self.calibration_timeout) and self.calibration_timeout > 0):
            raise ValueError(f"calibration_timeout must be finite and > 0, got {self.calibration_timeout}")


class PhaseSequence:
    """Start-up, shutdown and the safe stop, as methods of
    :class:`~giwbc.runtimes.realtime.RealtimeRuntime` (a mixin: they drive its cycles, phase and faults)."""

    def _set_phase(self, phase: Phase) -> None:
        self.phase = phase
        t = self._now
        if phase in (Phase.SHUTDOWN, Phase.DAMPING) and self.stop_deadline is None and self.clock.realtime:
            # The watchdog takes over a stop that runs longer than its nominal length plus a margin
            # (paced runs: robot time follows the wall clock; an unpaced run may be slower than it).
            s, c = self.startup, self.safety
            nominal = (s.shutdown_time + s.off_delay if phase == Phase.SHUTDOWN else c.damping_time) + (s.exit_attempts + 2) * self.period
            self.stop_deadline = time.perf_counter() + nominal + c.stop_margin
        self.phase_times.setdefault(phase, t)
        self.phase_cycles.setdefault(phase, len(self.clock.stats.lateness))
        self._event("phase", {"phase": phase})

    def _start_up(self) -> None:
        s = self.startup
        self.signals.install()
        if self.freeze_gc and not self._gc_frozen:
            gc.collect()
            gc.freeze()
            self._gc_frozen = True
        if self.gc_every is not None and self._gc_was_enabled is None:
            self._gc_was_enabled = gc.isenabled()
            gc.disable()  # collections happen between cycles: see the class docstring
        self._raise_priority()
        self._hold_cpu_latency()
        if self.watchdog is None:
            timeout = self.safety.watchdog_periods * self.period
            if not self.clock.realtime:  # an unpaced run (rehearsal, test) may be descheduled for a while: not a stuck loop
                timeout = max(timeout, UNPACED_WATCHDOG)
            self.watchdog = LoopWatchdog(self, timeout, rt_priority=self.rt_priority).start()
        self.armed = False
        if not self._joints_within_limits():
            self._safe_stop()
            return
        self._set_phase(Phase.ENABLE)
        report = self._special_frames(ENTER, s.enable_attempts, stop_on_fault=True)
        if self.fault is None and (report is None or not report.complete):
            missing = [self.description.joint_names[j] for j in np.flatnonzero(report.missing)] if report is not None else []
            self._fail(FaultKind.STARTUP, f"motors did not answer enter-motor-mode after {s.enable_attempts} tries: {missing}")
        if self.fault is not None:
            self._safe_stop()
            return
        self.robot.set_joint_impedance(self.damping)
        self.armed = True
        self._set_phase(Phase.SETTLE)
        self._run_for(s.settle_time, None)
        if self.fault is not None:
            self._safe_stop()
            return
        self.start_pose = q0 = self.robot.joint_positions()
        self._event("start_pose", {"q": q0})
        self._set_phase(Phase.RAMP)
        d = self.description
        target, kp, kd = d.default_positions, d.kp, d.kd
        profile = PROFILES[s.ramp_profile]
        t0, duration = self._now, max(s.ramp_time, self.period)

        def ramp() -> None:
            x = (self._now + self.period - t0) / duration  # the command acts from the next cycle
            phi, dphi = profile(x)
            g = min(1.0, x / s.gain_ramp) if s.gain_ramp > 0 else 1.0
            g, _ = cosine(g)
            self.robot.set_joint_impedance(ImpedanceCommand(
                q0 + (target - q0) * phi, (target - q0) * dphi / duration,
                g * kp, (1 - g) * self.damping.kd + g * kd, np.zeros(d.dofs),
            ))  # fmt: skip

        ramp()
        self._run_for(duration, ramp)
        if self.fault is None:
            self._calibrate()
        if self.fault is not None:
            self._safe_stop()
            return
        self._set_phase(Phase.RUNNING)

    def _calibrate(self) -> None:
        """Hold the ramp's last command (the default pose) until the state estimator is ready
        (module doc); a ``startup`` fault after ``calibration_timeout``."""
        estimator = self.calibrating_estimator
        if estimator is None or estimator.ready:
            return
        self._set_phase(Phase.CALIBRATE)
        timeout = self.startup.calibration_timeout
        end = self._now + timeout - 0.5 * self.period
        while not estimator.ready and self._now < end:
            self._cycle(None)
            if self.fault is not None:
                return
        if not estimator.ready:
            self._fail(FaultKind.STARTUP, f"the state estimator did not calibrate within {timeout:g} s: "
                                          f"still waiting for {estimator.waiting_for}")  # fmt: skip
            return
        report = estimator.calibration
        self._event("calibration", report.as_dict() if report is not None else {})

    def _joints_within_limits(self) -> bool:
        """Before any motor is enabled: read every joint with zero-gain, zero-torque commands (no
        torque, enabled or not) and refuse to start (a STARTUP fault naming each joint) when one
        reads outside its limits by more than ``start_limit_tolerance``: a wrong sign or zero
        offset in the plan, which enabling would turn into a violent move."""
        d = self.description
        self.robot.set_joint_impedance(ImpedanceCommand.damping(d.dofs, 0.0))
        for _ in range(1 + self.robot.reply_lag):
            self._cycle(None, COMMAND)
        q, heard = self.robot.joint_positions(), self.robot.replied_once
        lo, hi = d.position_limits
        tol = self.safety.start_limit_tolerance
        bad = np.flatnonzero(heard & np.isfinite(lo) & np.isfinite(hi) & ((q < lo - tol) | (q > hi + tol)))
        if not len(bad):
            return True
        names = tuple(d.joint_names[j] for j in bad)
        detail = "; ".join(
            f"{d.joint_names[j]} reads {q[j]:.3f} rad, limits [{lo[j]:.3f}, {hi[j]:.3f}]" for j in bad
        )
        self._fail(
            FaultKind.STARTUP,
            f"refusing to enable the motors: joint(s) outside their limits before start ({detail}). Check the plan's "
            "sign and zero_offset (giwbc motors calibrate) or move the joint back by hand",
            names,
        )
        return False

    def _shut_down(self) -> None:
        """Clean end: ramp the last command to damping, hold it, motors off."""
        s = self.startup
        self._set_phase(Phase.SHUTDOWN)
        self.armed = False
        last = self.robot.command
        t0, duration = self._now, max(s.shutdown_time, self.period)

        def ramp_down() -> None:
            x = (self._now + self.period - t0) / duration
            phi, _ = cosine(x)
            self.robot.set_joint_impedance(ImpedanceCommand(
                last.q_ref, (1 - phi) * last.v_ref, (1 - phi) * last.kp,
                (1 - phi) * last.kd + phi * self.damping.kd, (1 - phi) * last.tau_ff,
            ))  # fmt: skip

        ramp_down()
        self._run_for(duration, ramp_down)
        self.robot.set_joint_impedance(self.damping)
        self._set_phase(Phase.DAMPING)
        self._run_for(s.off_delay, None)
        self._motors_off()

    def _safe_stop(self) -> None:
        """After a fault: damping until ``damping_time`` after the detection, then motors off."""
        if self.phase == Phase.OFF:
            return
        self.armed = False
        self.robot.set_joint_impedance(self.damping)
        if self.phase != Phase.DAMPING:
            self._set_phase(Phase.DAMPING)
        until = self._stop_at if self._stop_at is not None else self._now + self.safety.damping_time
        self._run_for(until - self._now, None)
        self._motors_off()

    def _special_frames(self, kind: str, attempts: int, *, stop_on_fault: bool) -> CycleReport | None:
        """Send ``kind`` (enter / exit motor mode) frames every cycle until a cycle reads every
        motor's reply to them, at most ``attempts`` cycles (plus the robot's reply lag: replies
        read a cycle later when the motors answer on their own clock). Returns the last report."""
        lag = self.robot.reply_lag
        report = None
        for attempt in range(attempts + lag):
            report = self._cycle(None, kind)
            if attempt >= lag and report is not None and report.complete:
                break
            if stop_on_fault and self.fault is not None:
                break
        return report

    def _motors_off(self) -> None:
        if self.phase == Phase.OFF:
            return
        report = self._special_frames(EXIT, self.startup.exit_attempts, stop_on_fault=False)
        # Motors that never confirmed it (a dead bus): left to their own timeout.
        missing = report.missing if report is not None else np.ones(self.description.dofs, dtype=bool)
        self.unconfirmed_off = tuple(self.description.joint_names[j] for j in np.flatnonzero(missing))
        if self._gc_was_enabled is not None:
            self._event("garbage_collection", {"young_collections": self.gc_collections, "longest_us": round(1e6 * self.gc_seconds_max, 1)})
        self._set_phase(Phase.OFF)
        self._event("motors_off", {"fault": None if self.fault is None else str(self.fault), "unconfirmed": list(self.unconfirmed_off)})

    def _run_for(self, seconds: float, compute: Callable[[], None] | None) -> None:
        """Cycles until ``seconds`` of robot time passed (skipped slots count: time is the
        deadline slot's, and advances every cycle, whatever the exchange did: this ends); stops
        early on a new fault unless already stopping."""
        stopping = self.phase in (Phase.DAMPING, Phase.SHUTDOWN)
        end = self._now + seconds - 0.5 * self.period
        while self._now < end:
            self._cycle(compute)
            if self.fault is not None and not stopping:
                return
            if self.fault is not None and compute is not None:
                compute = None  # a fault during the shutdown ramp: straight to damping
                self.robot.set_joint_impedance(self.damping)


__all__ = ["UNPACED_WATCHDOG", "Phase", "PhaseSequence", "StartupConfig"]
