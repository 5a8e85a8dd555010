"""The real-time runtime: a ``gymnasium.Env`` running a Task on a :class:`CanRobot`, paced by
absolute deadlines.

Pacing: :mod:`giwbc.runtimes.clock` (absolute deadlines; the robot's time is the deadline slot's).

One control cycle: exchange with the motors (the command computed last cycle goes out, the state
comes back), safety checks, then the controller tick (the Task's ``apply_command``: the WBC at
the controller rate) computes the next command, then the cycle is logged: its records are built
after the cycle's work is counted done (the command is ready; the records use the rest of the
period, as the young-generation collections do, and a period they overflow shows as the next
cycle's lateness). The policy runs at the agent rate between :meth:`RealtimeRuntime.step` calls.

Phases (:mod:`giwbc.runtimes.phases`): idle -> enable -> settle -> ramp -> calibrate (with a
state estimator) -> running -> shutdown -> damping -> off; the process settings while the motors are on: :mod:`giwbc.runtimes.os_settings`.

Hand-over: after the ramp (and after every later reset) the task's first controller tick runs
between two cycles, while the motors hold their last command, and the schedule restarts after it
(:meth:`~giwbc.runtimes.clock.DeadlineClock.resync`): a whole-body controller's first tick lays out and cold-solves its
QP (milliseconds), which would otherwise overrun the first running cycle. The pause is logged.

Any fault (:mod:`giwbc.hal.safety`), a signal, a non-finite action or command, an exception of
any type (``KeyboardInterrupt`` included) in the policy, the controller, the task or a bus driver,
a controller that fell back (infeasible QP): damping goes out at the next exchange (within two
cycles of the detection), is held for ``damping_time``, then the motors are switched off; the
cause is logged and nothing escapes :meth:`RealtimeRuntime.run`.

Why this cannot hang: the runtime's time is the deadline slot's, so every cycle advances it
whether its exchange worked or not (a dead bus, a driver that raises), and every stop is a
bounded number of cycles. What a cycle cannot bound, a call that never returns (a driver blocked
forever, a hung policy), the **watchdog** (:mod:`giwbc.runtimes.watchdog`, a thread of its own)
handles: when the loop produces no cycle for ``watchdog_periods`` periods, or a safe stop overruns
its length by ``stop_margin``, it abandons the loop and stops the motors itself, damping then
off, from frames encoded in advance and sent by one thread per bus (a bus whose driver is stuck
cannot hold up the others; its motors fall back on their own timeout).
:meth:`RealtimeRuntime.run` runs the loop in a thread of its own and returns once the loop ended
or the watchdog's stop is done, so the caller (``giwbc deploy``) always gets its exit code.
"""

from __future__ import annotations

import gc
import math
import signal
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

from giwbc.hal.can_robot import COMMAND, CanRobot, CycleReport, NonFiniteCommand
from giwbc.hal.safety import Fault, FaultKind, SafetyConfig, SafetySupervisor, SignalWatch, damping_command
from giwbc.estimation.estimated_robot import EstimatedRobot
from giwbc.estimation.estimator import StateEstimator
from giwbc.robot.interface import ImpedanceCommand, RobotWrapper
from giwbc.runlog import CycleRecorder, RunLogWriter
from giwbc.runtimes.clock import DeadlineClock
from giwbc.runtimes.fault_response import FaultResponse, LoopAbandoned, describe, robot_faults
from giwbc.runtimes.os_settings import ProcessSettings, check_cpu_latency, check_rt_priority
from giwbc.runtimes.phases import Phase, PhaseSequence, StartupConfig
from giwbc.runtimes.watchdog import LoopWatchdog
from giwbc.tasks.rates import Rates
from giwbc.tasks.task import Task

STARTUP_PHASES = (Phase.IDLE, Phase.ENABLE, Phase.SETTLE, Phase.RAMP, Phase.CALIBRATE)  # run(progress=...) reports these
PROGRESS_PERIOD = 1.0  # s between the start-up's progress lines


# ----------------------------------------------------------------------------- runtime
@dataclass(frozen=True)
class RunResult:
    """How a run ended: ``ok`` (no fault), the first fault, all faults, timing, the log."""

    ok: bool
    fault: Fault | None
    faults: tuple[Fault, ...]
    cycles: int
    robot_time: float
    wall_time: float
    timing: dict[str, Any]
    phase_times: dict[str, float]
    log_path: str | None = None

    loop_abandoned: bool = False  # the watchdog stopped the motors; the loop's thread never came back
    unconfirmed_off: tuple[str, ...] = ()  # joints whose motors never confirmed exit-motor-mode (a dead bus)

    @property
    def exit_code(self) -> int:
        """0 clean, 128 + signal number for a signal (130 SIGINT, 143 SIGTERM), 130 for a
        ``KeyboardInterrupt``, 1 for any other fault (see :func:`exit_code_for`)."""
        return exit_code_for(self.fault)


def exit_code_for(fault: Fault | None) -> int:
    """The process exit code for a run that ended on ``fault``: 0 clean, 128 + the signal's number
    for a signal (130 SIGINT, 143 SIGTERM, 129 SIGHUP, 131 SIGQUIT), 130 for a ``KeyboardInterrupt``
    raised inside the loop, 1 for any other fault."""
    if fault is None:
        return 0
    if fault.kind is FaultKind.INTERRUPTED:
        return 130
    if fault.kind is FaultKind.SIGNAL:
        name = fault.message.rsplit(" ", 1)[-1]
        return 128 + signal.Signals[name].value if name in signal.Signals.__members__ else 143
    return 1


class RealtimeRuntime(PhaseSequence, FaultResponse, ProcessSettings, gymnasium.Env[np.ndarray, np.ndarray]):
    """Runs ``task`` on the CAN ``robot`` in real time (see the module docstring).

    ``robot``: a :class:`CanRobot`, or an :class:`~giwbc.estimation.estimated_robot.EstimatedRobot`
    around one (a base state for the controller). The task sees ``robot`` as given; the runtime
    drives the motors through the CAN robot (:attr:`robot`) and, after each exchange, updates the
    estimator (:attr:`estimated`) when a new IMU sample came, so it runs through start-up too.

    ``log``: a :class:`RunLogWriter` (owned by the caller) or None; ``log_every``: log commands,
    replies, IMU and estimate every this many cycles (faults, events: always); ``recorders``: the
    controller's own channels (e.g. the walker's state, :mod:`giwbc.apps.deploy_walk_log`), each
    asked for its record on the same cycles after the cycle's tick (their channels declared in ``log``). ``realtime=False``
    runs cycles back to back (the emulator follows the robot's nominal time, so the run is the same).
    ``rt_priority``: run under ``SCHED_FIFO`` at this priority while the motors are on (Linux, needs
    CAP_SYS_NICE; 1 to 99, else ValueError; refused here -> logged, run goes on: ``giwbc deploy`` probes it before any bus opens, :func:`~giwbc.runtimes.os_settings.probe_rt_priority`), restored at :meth:`close`; mind Linux RT
    throttling (``kernel.sched_rt_runtime_us``, 95 % by default): a loop thread busy (working or
    spinning) more than that in a second is stopped for the rest of it (~50 ms), so under
    ``SCHED_FIFO`` every cycle sleeps at least 6 % of the period, late or not. ``cpu_latency``:
    while the motors are on, hold the CPUs' wake-up latency at most this many µs (0: the idle CPUs
    poll) with a Linux PM QoS request (``/dev/cpu_dma_latency``, needs root; refused -> logged, run
    goes on; :mod:`giwbc.runtimes.os_settings`): a cycle that follows a sleep then starts on a CPU
    that did not halt; :attr:`cpu_idle` says what was granted. ``spin``: seconds
    spent spinning before each deadline (default 250 us, 100 us under ``SCHED_FIFO``). ``freeze_gc``: collect
    garbage before the motors start, then ``gc.freeze()`` what exists (a full collection of the whole
    heap costs tens of ms: a stalled loop), ``gc.unfreeze()`` at :meth:`close`. ``gc_every``: while
    the motors are on, Python's automatic collection is off and the runtime collects the young
    generations itself every this many cycles, right after a cycle's work (~5-30 us: they hold a
    few hundred objects), instead of an automatic collection firing inside a cycle (measured
    ~0.8 ms for a generation-1 collection there, ~12 ms for a full one); the automatic collector
    is restored at :meth:`close`. None: leave it to Python.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        task: Task,
        robot: CanRobot | EstimatedRobot,
        *,
        agent_rate: float = 50.0,
        controller_rate: float | None = None,
        safety: SafetyConfig | None = None,
        startup: StartupConfig | None = None,
        log: RunLogWriter | None = None,
        log_every: int = 1,
        realtime: bool = True,
        spin: float | None = None,
        rt_priority: int | None = None,
        cpu_latency: float | None = None,
        freeze_gc: bool = True,
        gc_every: int | None = 500,
        recorders: Sequence[CycleRecorder] = (),
    ) -> None:
        can = robot.unwrapped if isinstance(robot, RobotWrapper) else robot
        if not isinstance(can, CanRobot):
            raise TypeError(f"the real-time runtime drives a CanRobot (or a wrapper of one), got {type(robot).__name__}")
        self.estimated = robot if isinstance(robot, EstimatedRobot) else None  # updated after every exchange
        controller_rate = float(controller_rate or can.plan.control_rate)
        self.rates = Rates(agent=agent_rate, controller=controller_rate, physics=controller_rate)
        self.task, self.robot = task, can  # the task sees the robot as given; the runtime drives the motors
        task.bind(robot, self.rates)
        self.action_space = task.action_space
        self.observation_space = task.observation_space
        self.description = d = can.description
        self.safety = safety or SafetyConfig()
        self.startup = startup or StartupConfig()
        self.supervisor = SafetySupervisor(d, self.safety, bus_names=tuple(b.name for b in can.plan.buses))
        self.signals = SignalWatch()
        self.rt_priority = check_rt_priority(rt_priority)
        self.freeze_gc = freeze_gc
        self._gc_frozen = False
        self.gc_every = None if gc_every is None else max(1, int(gc_every))
        self._gc_was_enabled: bool | None = None  # automatic collection before the motors started (when turned off)
        self.gc_collections, self.gc_seconds_max = 0, 0.0
        self._schedulers: list[tuple[int, tuple[int, Any]]] = []
        self.scheduler = "default"  # the loop thread's scheduling while the motors were on, as granted
        self.cpu_latency = check_cpu_latency(cpu_latency)
        self.cpu_idle = "default"  # the CPUs' idle states while the motors were on, as granted
        self._cpu_latency_fd: int | None = None
        if spin is None:  # under SCHED_FIFO wake-ups are prompt; spinning counts against RT throttling
            spin = 100e-6 if rt_priority is not None else 250e-6
        min_idle = 0.06 / controller_rate if rt_priority is not None else 0.0  # stay under 95 % busy
        self.clock = DeadlineClock(1.0 / controller_rate, realtime=realtime, spin=spin, min_idle=min_idle)
        self.period = 1.0 / controller_rate
        self._ticks_per_step = self.rates.physics_per_agent // self.rates.physics_per_controller
        self.log = log
        self.log_path = str(log.path) if log is not None else None
        self.log_every = max(1, int(log_every))
        self.recorders = tuple(recorders)
        self.damping = damping_command(d, self.safety)
        self.phase = Phase.IDLE
        self.fault: Fault | None = None
        self.faults: list[Fault] = []
        self.phase_times: dict[str, float] = {}
        self.phase_cycles: dict[str, int] = {}  # index of each phase's first cycle in the clock's stats
        self.armed = False
        self.start_pose: np.ndarray | None = None
        self._observation: np.ndarray | None = None
        self._stop_at: float | None = None
        self._wall0 = 0.0
        self._cycles = 0
        self._clamp_noted = False
        self._now = 0.0  # the current cycle's slot time: advances every cycle, whatever the exchange did
        self._fault_lock = threading.RLock()
        self._log_lock = threading.RLock()  # the run log is written by the loop and, once, by the watchdog
        self._exchange_lock = threading.Lock()  # held by the loop during an exchange
        self._abandoned = False  # the watchdog took over: the loop's thread must not touch the motors again
        self.taken_over = threading.Event()  # set once the watchdog's stop is done
        self.stop_deadline: float | None = None  # perf_counter time by which a running stop must have ended
        self.watchdog: LoopWatchdog | None = None
        self.emergency: dict[str, Any] | None = None  # what the watchdog's stop reached
        self._driver_errors_seen: set[int] = set()
        self._loop_thread: threading.Thread | None = None
        self._wake = threading.Event()
        self.unconfirmed_off: tuple[str, ...] = ()  # joints whose motors did not confirm exit-motor-mode

    # --- gymnasium API ----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start the robot (enable, settle, ramp) the first time, then reset the task."""
        super().reset(seed=seed)
        if self.phase not in (Phase.IDLE, Phase.RUNNING):
            raise RuntimeError(f"the motors are {self.phase}: build a new runtime to start again ({self.fault})")
        self.task.np_random = self.np_random
        if self.phase == Phase.IDLE:
            self._start_up()
        if self.fault is None:
            try:
                self.task.reset_task()
                self._hand_over()
                self._observation = self._observe()
            except NonFiniteCommand as error:
                self._fail(FaultKind.NONFINITE_COMMAND, f"controller output is not finite: {error}")
            except LoopAbandoned:
                raise
            except BaseException as error:  # noqa: BLE001 - no exception escapes the loop
                self._fail_on(error, FaultKind.CONTROLLER_ERROR, "task reset failed")
            failure = self._controller_failure()
            if failure is not None and self.fault is None:
                self._fail(FaultKind.CONTROLLER_FAILED, failure)
        return self._last_observation(), self._info()

    def _hand_over(self) -> None:
        """The task's first controller tick after a reset, between two cycles (module docstring):
        it pays the controller's one-time costs (the G1 WBC lays out its QP and solves it cold:
        ~1.5-3 ms) while the motors hold their last command, then the deadline schedule restarts,
        instead of the first running cycle overrunning by that much. Its command goes out at the
        next exchange, as any cycle's does."""
        started = time.perf_counter()
        self._control_tick()
        pause = time.perf_counter() - started
        self.clock.resync()
        self._event("handover", {"pause_ms": round(1e3 * pause, 3)})

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One agent step: the action, then ``controller / agent`` control cycles."""
        if self.phase != Phase.RUNNING or self.fault is not None:
            return self._last_observation(), 0.0, True, False, self._info()
        try:
            try:
                array = np.asarray(action, dtype=float)
                if array.shape != self.action_space.shape or not np.all(np.isfinite(array)):
                    return self._abort(FaultKind.NONFINITE_POLICY, f"policy action is not {self.action_space.shape} finite numbers: {array}")
                self.task.set_action(self.task.validate_action(array))
            except LoopAbandoned:
                raise
            except BaseException as error:  # noqa: BLE001
                return self._abort_on(error, FaultKind.POLICY_ERROR, "action rejected")
            for _ in range(self._ticks_per_step):
                self._cycle(self._control_tick)
                if self.fault is not None:
                    break
            if self.fault is not None:
                self._safe_stop()
                return self._last_observation(), 0.0, True, False, self._info()
            try:
                self._observation = self._observe()
                reward = float(self.task.get_reward())
                if self.task.is_terminated():
                    return self._abort(FaultKind.TASK_TERMINATED, f"the task ended the episode (fall): {self.task.get_info()}")
                truncated = bool(self.task.is_truncated())
            except LoopAbandoned:
                raise
            except BaseException as error:  # noqa: BLE001
                return self._abort_on(error, FaultKind.CONTROLLER_ERROR, "task raised")
            return self._observation, reward, False, truncated, self._info()
        except LoopAbandoned:  # the watchdog stopped the motors (this thread was stuck)
            return self._last_observation(), 0.0, True, False, self._info()

    def close(self) -> None:
        """Stop the motors if they are on (after a fault: damping then off; otherwise the clean
        shutdown ramp), then restore the signal handlers. Never raises."""
        try:
            if self._abandoned:
                pass  # the watchdog stopped the motors
            elif self.fault is not None or self.phase in (Phase.ENABLE, Phase.SHUTDOWN, Phase.DAMPING):
                self._safe_stop()
            elif self.phase in (Phase.SETTLE, Phase.RAMP, Phase.CALIBRATE, Phase.RUNNING):
                self._shut_down()
        except LoopAbandoned:
            pass
        except BaseException as error:  # noqa: BLE001 - last resort: motors off
            self._fail_on(error, FaultKind.INTERNAL, "shutdown raised")
            try:
                if not self._abandoned:
                    self._motors_off()
            except BaseException:  # noqa: BLE001
                pass
        finally:
            if self.watchdog is not None and not self._abandoned:
                self.watchdog.stop()
            self.signals.restore()
            self._restore_priority()
            self._restore_process_state()

    # --- the deploy loop --------------------------------------------------------------------
    def run(
        self, policy: Callable[[np.ndarray], np.ndarray] | None = None, seconds: float = 10.0, progress: Callable[[str], None] | None = None
    ) -> RunResult:
        """Start, run ``policy`` (None: zero actions) for ``seconds`` of control, shut down.
        Never raises: the outcome is in the :class:`RunResult`. ``progress``: told (from this
        thread, never the loop's) what the start-up does and waits for: each phase as it begins and,
        while the state estimator calibrates, once a second what it still waits for
        (:meth:`startup_status`); silent once running.

        The loop runs in a thread of its own ("giwbc-control"); this thread installs the signal
        handlers (only the main thread can) and waits until the loop ended, or until the watchdog
        stopped the motors of a loop that never came back (then the result says
        ``loop_abandoned``), so it always returns."""
        self._wall0 = time.perf_counter()
        self.signals.install()
        done = threading.Event()
        self._wake = wake = threading.Event()  # set when the loop ends or the watchdog's stop is done
        self._loop_thread = thread = threading.Thread(target=self._loop, args=(policy, seconds, done), name="giwbc-control", daemon=True)
        try:
            thread.start()
            said = ""
            while not done.is_set():
                try:
                    starting = progress is not None and self.phase in STARTUP_PHASES and self.fault is None
                    if starting:
                        wake.wait(PROGRESS_PERIOD)  # once a second during the start-up only
                        status = self.startup_status()
                        if status and (status != said or self.phase == Phase.CALIBRATE):
                            progress(status)  # type: ignore[misc]
                            said = status
                        continue
                    wake.wait()  # (no polling: every wake-up would take the interpreter lock from the loop)
                    if not done.is_set() and self.taken_over.is_set():
                        done.wait(max(0.05, 5 * self.period))  # a last chance for the loop's thread to leave
                        break
                except KeyboardInterrupt:  # only without our handler (not the main thread): stop as SIGINT would
                    self.signals.trigger(signal.SIGINT)
        finally:
            self.signals.restore()
            if not done.is_set():  # the loop's thread never came back: undo what it changed for the process
                self._restore_process_state()
        return self.result()

    def _loop(self, policy: Callable[[np.ndarray], np.ndarray] | None, seconds: float, done: threading.Event) -> None:
        """The control loop (see :meth:`run`): every way out of it ends in :meth:`close`."""
        try:
            try:
                observation, _ = self.reset()
                zeros = np.zeros(self.action_space.shape, dtype=np.float32)
                end = self._now + seconds
                while self.fault is None and self._now < end - 1e-9:
                    try:
                        action = zeros if policy is None else policy(observation)
                    except LoopAbandoned:
                        raise
                    except BaseException as error:  # noqa: BLE001 - KeyboardInterrupt included
                        self._abort_on(error, FaultKind.POLICY_ERROR, "policy raised")
                        break
                    observation, _, terminated, truncated, _ = self.step(action)
                    if terminated or truncated:
                        break
            except LoopAbandoned:
                pass
            except BaseException as error:  # noqa: BLE001 - a bug must still end in damping and motors off
                self._fail_on(error, FaultKind.INTERNAL, f"runtime error\n{traceback.format_exc(limit=4)}")
            finally:
                self.close()
        except BaseException:  # noqa: BLE001 - nothing escapes this thread (close() never raises)
            pass
        finally:
            done.set()
            self._wake.set()

    def startup_status(self) -> str:
        """What the start-up is doing and, while calibrating, what it waits for ("" outside the start-up)."""
        phase, now = self.phase, self._now
        if phase == Phase.ENABLE:
            return "enabling the motors"
        if phase == Phase.SETTLE:
            return "motors on, damping: reading the pose"
        if phase == Phase.RAMP:
            return f"ramping to the default pose ({self.startup.ramp_time:g} s)"
        if phase == Phase.CALIBRATE:
            since = now - self.phase_times.get(Phase.CALIBRATE, now)
            estimator = self.calibrating_estimator
            waiting = estimator.waiting_for if estimator is not None else ""
            return (f"calibrating the IMU: hold the robot still, on both feet ({since:.0f} of at most "
                    f"{self.startup.calibration_timeout:g} s; waiting for {waiting})")  # fmt: skip
        return ""

    def result(self) -> RunResult:
        return RunResult(
            ok=self.fault is None,
            fault=self.fault,
            faults=tuple(self.faults),
            cycles=self._cycles,
            robot_time=self._now,
            wall_time=time.perf_counter() - self._wall0 if self._wall0 else 0.0,
            timing=self.clock.stats.summary(self.period),
            phase_times=dict(self.phase_times),
            log_path=self.log_path,
            loop_abandoned=self._abandoned and self._loop_thread is not None and self._loop_thread.is_alive(),
            unconfirmed_off=self.unconfirmed_off,
        )

    # --- one control cycle ------------------------------------------------------------------
    def _control_tick(self) -> None:
        self.task.apply_command()

    def _cycle(self, compute: Callable[[], None] | None, kind: str = COMMAND) -> CycleReport | None:
        """Wait for the slot, exchange, check, compute the next command, log. Never raises, but
        :class:`LoopAbandoned` once the watchdog took over."""
        if self._abandoned:
            raise LoopAbandoned
        robot, log = self.robot, self.log
        slot, lateness = self.clock.wait()
        self._now = t = slot * self.period
        sent = robot.command
        report: CycleReport | None = None
        try:
            with self._exchange_lock:  # the watchdog's stop never sends while an exchange is under way
                if self._abandoned:
                    raise LoopAbandoned
                # A full period for the exchange from the cycle's actual start: a late cycle still sends.
                report = robot.exchange(t, deadline=self.clock.cycle_start + self.period if self.clock.realtime else None, kind=kind)
                if self.estimated is not None:
                    self.estimated.update(fuse=report.imu_fresh)  # the base state for this cycle's tick
        except LoopAbandoned:
            raise
        except BaseException as error:  # noqa: BLE001 - KeyboardInterrupt included; the next cycle tries again
            if self._abandoned:
                raise LoopAbandoned from None
            self._fail_on(error, FaultKind.DRIVER_ERROR, "exchange raised")
        if self._abandoned:
            raise LoopAbandoned
        self._cycles += 1
        if self.signals.poll() is not None and not any(f.kind is FaultKind.SIGNAL for f in self.faults):
            self._fail(FaultKind.SIGNAL, f"stopped by {self.signals.name}")
        if report is not None:
            imu = robot.latest_imu
            if self.armed:
                try:
                    for fault in robot_faults(self.supervisor, robot, report):
                        self._fail(fault.kind, fault.message, fault.joints)
                except Exception as error:  # noqa: BLE001
                    self._fail(FaultKind.INTERNAL, f"safety check raised: {describe(error)}")
            if self.armed and lateness > self.safety.max_stall:
                self._fail(FaultKind.TIMING, f"control loop stalled: cycle started {1e3 * lateness:.1f} ms after its deadline")
            if report.driver_errors and any(e is not None for e in report.driver_errors):
                self._driver_error_event(report)
            if compute is not None and self.fault is None:
                try:
                    compute()
                except NonFiniteCommand as error:
                    self._fail(FaultKind.NONFINITE_COMMAND, f"controller output is not finite: {error}")
                except LoopAbandoned:
                    raise
                except BaseException as error:  # noqa: BLE001 - KeyboardInterrupt included
                    self._fail_on(error, FaultKind.CONTROLLER_ERROR, "controller raised")
                if compute == self._control_tick and self.fault is None:
                    failure = self._controller_failure()
                    if failure is not None:
                        self._fail(FaultKind.CONTROLLER_FAILED, failure)
        work, overrun = self.clock.done()
        if log is not None and report is not None:  # after the work: the command is ready, the records wait
            try:
                self._log_lock.acquire()
                if self._abandoned:
                    raise LoopAbandoned
                if report.cycle % self.log_every == 0:
                    self._log_cycle(report, sent, kind, imu)
                if report.clamped and not self._clamp_noted:
                    self._clamp_noted = True
                    fields = ("position", "velocity", "kp", "kd", "torque")
                    counts = {f"{self.description.joint_names[j]}.{fields[k]}": int(robot.clamp_counts[j, k])
                              for j, k in zip(*np.nonzero(robot.clamp_counts))}  # fmt: skip
                    log.event(report.cycle, t, "clamped", {"note": "command fields clamped to the motors' ranges", "fields": counts})
            except Exception as error:  # noqa: BLE001 - the robot must not depend on its log
                self._log_failed(error)
            finally:
                self._log_lock.release()
        if self._gc_was_enabled is not None and self._cycles % self.gc_every == 0:  # type: ignore[operator]
            started = time.perf_counter()
            gc.collect(1)  # the young generations, in this cycle's slack
            self.gc_collections += 1
            self.gc_seconds_max = max(self.gc_seconds_max, time.perf_counter() - started)
        if self.log is not None and report is not None and report.cycle % self.log_every == 0:
            st = self.clock.stats
            period = st.periods[-1] * 1e6 if st.periods and math.isfinite(st.periods[-1]) else None
            with self._log_lock:
                if self._abandoned:
                    raise LoopAbandoned
                try:
                    self.log.timing(report.cycle, t, slot, lateness * 1e6, period, work * 1e6, report.send_s * 1e6,
                                    report.receive_s * 1e6, overrun)  # fmt: skip
                    self.log.flush()  # the cycle's records, to the logger process in one datagram
                except Exception as error:  # noqa: BLE001
                    self._log_failed(error)
        return report

    def _event(self, name: str, detail: dict[str, Any]) -> None:
        if self.log is not None and self._log_lock.acquire(timeout=0.5):  # (a loop stuck in the log: the watchdog logs nothing)
            try:
                self.log.event(max(0, self.robot.cycle - 1), self._now, name, detail)
            except Exception as error:  # noqa: BLE001
                self._log_failed(error)
            finally:
                self._log_lock.release()

    def _log_failed(self, error: BaseException) -> None:
        """Logging broke: stop logging (kept in the faults as an internal error), keep controlling."""
        self.log = None
        if not any(f.kind is FaultKind.INTERNAL for f in self.faults):
            self.faults.append(Fault(FaultKind.INTERNAL, f"run log failed, logging stopped: {describe(error)}",
                                     max(0, self.robot.cycle - 1), self._now))  # fmt: skip

    def _log_cycle(self, report: CycleReport, sent: ImpedanceCommand, kind: str, imu: Any) -> None:
        log, robot, t = self.log, self.robot, report.time
        assert log is not None
        log.commands(report.cycle, t, self.phase, kind, sent.q_ref, sent.v_ref, sent.kp, sent.kd, sent.tau_ff)
        q, dq, tau = robot.measured
        log.replies(report.cycle, t, q, dq, tau, report.temperature, report.error_code,
                    report.missing, report.late, int(report.corrupt.sum()), report.unknown)  # fmt: skip
        estimate = self.estimated.latest_estimate if self.estimated is not None else None
        if imu is not None or estimate is not None:
            log.estimator(report.cycle, t, imu, estimate)
        for recorder in self.recorders:  # the cycle's tick, if there was one (its command goes out next cycle)
            values = recorder.sample()
            if values is not None:
                log.channel(recorder.channel.topic, report.cycle, t, values)

    # --- helpers ----------------------------------------------------------------------------
    @property
    def calibrating_estimator(self) -> StateEstimator | None:
        """The state estimator the start-up calibrates (the :class:`EstimatedRobot`'s, when its
        ``calibrate`` is on), or None."""
        estimator = self.estimated.estimator if self.estimated is not None else None
        return estimator if estimator is not None and estimator.config.calibrate else None

    def _observe(self) -> np.ndarray:
        observation = np.asarray(self.task.get_observation(), dtype=np.float64)
        low, high = self.observation_space.low, self.observation_space.high
        return np.minimum(np.maximum(observation, low), high).astype(self.observation_space.dtype)

    def _last_observation(self) -> np.ndarray:
        if self._observation is not None:
            return self._observation
        return np.zeros(self.observation_space.shape, dtype=self.observation_space.dtype)

    def _info(self) -> dict[str, Any]:
        info: dict[str, Any] = {"time": self._now, "phase": self.phase, "cycle": self.robot.cycle}
        if self.fault is not None:
            info["fault"] = self.fault.as_dict()
        return info


__all__ = ["RealtimeRuntime", "RunResult", "exit_code_for"]
