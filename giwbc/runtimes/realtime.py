"""The real-time runtime: a ``gymnasium.Env`` running a Task on a :class:`CanRobot`, paced by
absolute deadlines.

Pacing (:class:`DeadlineClock`): control cycle ``k`` is due at ``start + k * period`` on
``time.perf_counter()``; the loop sleeps until ``spin`` before the deadline, then spins. A cycle
whose work ends after the next deadline is an **overrun**; when a whole period is missed the
clock skips to the current slot (counted as skipped) instead of bursting to catch up. The robot's
time is the slot's nominal time ``k * period``, which is also the clock the emulator runs on.

One control cycle: exchange with the motors (the command computed last cycle goes out, the state
comes back), safety checks, then the controller tick (the Task's ``apply_command``: the WBC at
the controller rate) computes the next command, then the cycle is logged. The policy runs at the
agent rate between :meth:`RealtimeRuntime.step` calls.

Phases::

    idle -> enable (enter motor mode) -> settle (damping) -> ramp (measured pose -> default pose)
         -> running (controller) -> shutdown (ramp to damping) -> damping -> off (exit motor mode)

Hand-over: after the ramp (and after every later reset) the task's first controller tick runs
between two cycles, while the motors hold their last command, and the schedule restarts after it
(:meth:`DeadlineClock.resync`): a whole-body controller's first tick lays out and cold-solves its
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
import os
import signal
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import gymnasium
import numpy as np
from gymnasium import spaces

from giwbc.hal.can_robot import COMMAND, ENTER, EXIT, CanRobot, CycleReport, NonFiniteCommand
from giwbc.hal.runlog import RunLogWriter
from giwbc.hal.safety import Fault, FaultKind, SafetyConfig, SafetySupervisor, SignalWatch, damping_command
from giwbc.robot.interface import ImpedanceCommand, Robot, quat_to_matrix
from giwbc.runtimes.watchdog import EmergencyStop, LoopWatchdog
from giwbc.tasks.rates import Rates
from giwbc.tasks.task import Task

UNPACED_WATCHDOG = 1.0  # s: the watchdog's least timeout when the loop is not paced by the wall clock
IDLE, ENABLE, SETTLE, RAMP, RUNNING, SHUTDOWN, DAMPING, OFF = (
    "idle", "enable", "settle", "ramp", "running", "shutdown", "damping", "off",
)  # fmt: skip


# ----------------------------------------------------------------------------- pacing
def min_jerk(s: float) -> tuple[float, float]:
    """Minimum-jerk profile ``10 s^3 - 15 s^4 + 6 s^5`` on [0, 1] and its derivative."""
    s = min(1.0, max(0.0, s))
    return s**3 * (10 - 15 * s + 6 * s * s), 30 * s * s * (1 - s) ** 2


def cosine(s: float) -> tuple[float, float]:
    """Cosine profile ``(1 - cos(pi s)) / 2`` on [0, 1] and its derivative."""
    s = min(1.0, max(0.0, s))
    return 0.5 * (1 - math.cos(math.pi * s)), 0.5 * math.pi * math.sin(math.pi * s)


PROFILES: dict[str, Callable[[float], tuple[float, float]]] = {"minjerk": min_jerk, "cosine": cosine}


@dataclass
class TimingStats:
    """Per-cycle timing, seconds: lateness of each cycle start (after its deadline), period since
    the previous start (NaN for the first), work (wall) and CPU time, overrun flag, skipped slots."""

    lateness: list[float] = field(default_factory=list)
    periods: list[float] = field(default_factory=list)
    work: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)
    overrun: list[bool] = field(default_factory=list)
    skipped_before: list[int] = field(default_factory=list)

    @property
    def overruns(self) -> int:
        return int(sum(self.overrun))

    @property
    def skipped(self) -> int:
        return int(sum(self.skipped_before))

    def between(self, start: int, stop: int | None = None) -> TimingStats:
        """The cycles ``start:stop`` (e.g. one phase)."""
        s = slice(start, stop)
        return TimingStats(self.lateness[s], self.periods[s], self.work[s], self.cpu[s], self.overrun[s], self.skipped_before[s])

    def summary(self, period: float) -> dict[str, Any]:
        """p50 / p99 / max in microseconds (period error = |period - nominal|), overrun counts."""

        def pct(values: Any, scale: float = 1e6) -> dict[str, float | None]:
            a = np.asarray(values, dtype=float) * scale
            a = a[np.isfinite(a)]
            if not a.size:
                return {"p50": None, "p99": None, "max": None}
            return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}

        return {
            "cycles": len(self.lateness),
            "period_us": period * 1e6,
            "period_error_us": pct(np.abs(np.asarray(self.periods, dtype=float) - period)),
            "lateness_us": pct(self.lateness),
            "work_us": pct(self.work),
            "cpu_us": pct(self.cpu),
            "overruns": self.overruns,
            "skipped_slots": self.skipped,
        }


class DeadlineClock:
    """Absolute deadlines ``start + k * period`` on ``perf_counter`` (see the module docstring).

    ``realtime=False`` runs slots back to back (tests, faster-than-real-time rehearsals): the
    robot time still advances one period per cycle, so an emulated run is the same.
    """

    def __init__(self, period: float, *, realtime: bool = True, spin: float = 250e-6, min_idle: float = 0.0) -> None:
        if not period > 0 or spin < 0 or not 0 <= min_idle < period:
            raise ValueError(f"need period > 0, spin >= 0, 0 <= min_idle < period; got {period}, {spin}, {min_idle}")
        self.period = float(period)
        self.realtime = realtime
        self.spin = float(spin)
        self.min_idle = float(min_idle)  # sleep at least this long per cycle, even when late
        self.start: float | None = None
        self.slot = -1
        self.stats = TimingStats()
        self._last_start: float | None = None
        self._cycle_start = 0.0
        self._cpu_start = 0.0

    def deadline(self, slot: int) -> float:
        assert self.start is not None
        return self.start + slot * self.period

    @property
    def next_deadline(self) -> float:
        return self.deadline(self.slot + 1)

    @property
    def cycle_start(self) -> float:
        """When the current cycle actually started (``perf_counter``)."""
        return self._cycle_start

    def wait(self) -> tuple[int, float]:
        """Block until the next slot is due; returns (slot, lateness in s)."""
        clock = time.perf_counter
        if self.start is None:
            self.start = clock()
        slot = self.slot + 1
        if not self.realtime:
            self.slot = slot
            now = clock()
            self._begin(now, 0.0, 0)
            return slot, 0.0
        due = self.deadline(slot)
        now = clock()
        if self.min_idle and now > due - self.min_idle:
            # Late or nearly: yield anyway, so a busy loop under SCHED_FIFO stays below the kernel's
            # RT throttling limit (exceeding it stops the thread for the rest of the second).
            time.sleep(self.min_idle)
            now = clock()
        skipped = 0
        if now - due >= self.period:  # missed at least one whole slot: resynchronise
            current = int((now - self.start) / self.period)
            skipped = current - slot
            slot = current
        else:
            remaining = due - now - self.spin
            if remaining > 0:
                time.sleep(remaining)
            while clock() < due:
                pass
            now = clock()
        self.slot = slot
        lateness = now - due  # from the deadline this cycle was first due at (skips included)
        self._begin(now, lateness, skipped)
        return slot, lateness

    def resync(self) -> None:
        """Restart the schedule from now: the next slot is due one period from now. After a
        deliberate pause between cycles (the hand-over) nothing counts as an overrun or a skipped
        slot, and the period across the pause is not measured (NaN)."""
        if self.realtime and self.start is not None:
            self.start = time.perf_counter() - self.slot * self.period
            self._last_start = None

    def _begin(self, now: float, lateness: float, skipped: int) -> None:
        st = self.stats
        st.periods.append(now - self._last_start if self._last_start is not None else math.nan)
        self._last_start = now
        st.lateness.append(lateness)
        st.skipped_before.append(skipped)
        self._cycle_start = now
        self._cpu_start = time.thread_time()

    def done(self) -> tuple[float, bool]:
        """End of the cycle's work: (work seconds, overrun)."""
        now = time.perf_counter()
        work = now - self._cycle_start
        st = self.stats
        st.work.append(work)
        st.cpu.append(time.thread_time() - self._cpu_start)
        overrun = self.realtime and now > self.next_deadline
        st.overrun.append(overrun)
        return work, overrun


# ----------------------------------------------------------------------------- tasks
class Controller(Protocol):
    """Anything mapping the robot's state to the next impedance command."""

    def __call__(self, robot: Robot) -> ImpedanceCommand: ...


class StandingTask(Task):
    """A task with no action: a controller holds the robot, the observation is proprioception.

    The deployment task when no policy is given. Observation: gravity in the IMU frame, IMU
    angular rate, joint positions minus the default pose, joint velocities.
    """

    def __init__(self, controller: Controller, default_positions: np.ndarray) -> None:
        super().__init__()
        self.controller = controller
        self.default_positions = np.asarray(default_positions, dtype=float)

    def create_spaces(self) -> tuple[spaces.Box, spaces.Box]:
        n = self.robot.dofs
        high = np.concatenate([np.ones(3), np.full(3 + 2 * n, np.inf)]).astype(np.float32)
        return spaces.Box(-1.0, 1.0, shape=(0,), dtype=np.float32), spaces.Box(-high, high, dtype=np.float32)

    def reset_task(self) -> None:
        reset = getattr(self.controller, "reset", None)
        if callable(reset):
            reset()

    def set_action(self, action: np.ndarray) -> None:
        pass

    def apply_command(self) -> None:
        self.robot.set_joint_impedance(self.controller(self.robot))

    def controller_failure(self) -> str | None:
        """The controller's ``failure()`` (a WBC that fell back), if it has one."""
        failure = getattr(self.controller, "failure", None)
        return failure() if failure is not None else None

    def get_observation(self) -> np.ndarray:
        robot = self.robot
        imu = robot.imu()
        return np.concatenate([
            -quat_to_matrix(imu.quaternion)[2], imu.angular_velocity,
            robot.joint_positions() - self.default_positions, robot.joint_velocities(),
        ]).astype(np.float32)  # fmt: skip

    def get_reward(self) -> float:
        return 0.0

    def is_terminated(self) -> bool:
        return False


# ----------------------------------------------------------------------------- runtime
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

    def __post_init__(self) -> None:
        if self.ramp_profile not in PROFILES:
            raise ValueError(f"ramp_profile must be one of {list(PROFILES)}, got {self.ramp_profile!r}")
        if min(self.settle_time, self.ramp_time, self.shutdown_time, self.off_delay) < 0 or self.enable_attempts < 1:
            raise ValueError("start-up times must be >= 0 and enable_attempts >= 1")


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


class LoopAbandoned(BaseException):
    """Raised in the loop's thread once the watchdog took over: the loop must not touch the motors."""


class RealtimeRuntime(gymnasium.Env[np.ndarray, np.ndarray]):
    """Runs ``task`` on the CAN ``robot`` in real time (see the module docstring).

    ``log``: a :class:`RunLogWriter` (owned by the caller) or None; ``log_every``: log commands,
    replies, IMU and estimate every this many cycles (faults, events: always). ``realtime=False``
    runs cycles back to back (the emulator follows the robot's nominal time, so the run is the same).
    ``rt_priority``: run under ``SCHED_FIFO`` at this priority while the motors are on (Linux, needs
    CAP_SYS_NICE; refused -> logged, run goes on), restored at :meth:`close`; mind Linux RT
    throttling (``kernel.sched_rt_runtime_us``, 95 % by default): a loop thread busy (working or
    spinning) more than that in a second is stopped for the rest of it (~50 ms), so under
    ``SCHED_FIFO`` every cycle sleeps at least 6 % of the period, late or not. ``spin``: seconds
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
        robot: CanRobot,
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
        freeze_gc: bool = True,
        gc_every: int | None = 500,
    ) -> None:
        controller_rate = float(controller_rate or robot.plan.control_rate)
        self.rates = Rates(agent=agent_rate, controller=controller_rate, physics=controller_rate)
        self.task, self.robot = task, robot
        task.bind(robot, self.rates)
        self.action_space = task.action_space
        self.observation_space = task.observation_space
        self.description = d = robot.description
        self.safety = safety or SafetyConfig()
        self.startup = startup or StartupConfig()
        self.supervisor = SafetySupervisor(d, self.safety, bus_names=tuple(b.name for b in robot.plan.buses))
        self.signals = SignalWatch()
        self.rt_priority = rt_priority
        self.freeze_gc = freeze_gc
        self._gc_frozen = False
        self.gc_every = None if gc_every is None else max(1, int(gc_every))
        self._gc_was_enabled: bool | None = None  # automatic collection before the motors started (when turned off)
        self.gc_collections, self.gc_seconds_max = 0, 0.0
        self._schedulers: list[tuple[int, tuple[int, Any]]] = []
        self.scheduler = "default"  # the loop thread's scheduling while the motors were on, as granted
        if spin is None:  # under SCHED_FIFO wake-ups are prompt; spinning counts against RT throttling
            spin = 100e-6 if rt_priority is not None else 250e-6
        min_idle = 0.06 / controller_rate if rt_priority is not None else 0.0  # stay under 95 % busy
        self.clock = DeadlineClock(1.0 / controller_rate, realtime=realtime, spin=spin, min_idle=min_idle)
        self.period = 1.0 / controller_rate
        self._ticks_per_step = self.rates.physics_per_agent // self.rates.physics_per_controller
        self.log = log
        self.log_path = str(log.path) if log is not None else None
        self.log_every = max(1, int(log_every))
        self.damping = damping_command(d, self.safety)
        self.phase = IDLE
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
        if self.phase not in (IDLE, RUNNING):
            raise RuntimeError(f"the motors are {self.phase}: build a new runtime to start again ({self.fault})")
        self.task.np_random = self.np_random
        if self.phase == IDLE:
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
        if self.phase != RUNNING or self.fault is not None:
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
            elif self.fault is not None or self.phase in (ENABLE, SHUTDOWN, DAMPING):
                self._safe_stop()
            elif self.phase in (SETTLE, RAMP, RUNNING):
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

    def _restore_process_state(self) -> None:
        """The garbage collector as it was before the motors started."""
        if self._gc_was_enabled is not None:
            if self._gc_was_enabled:
                gc.enable()
            self._gc_was_enabled = None
        if self._gc_frozen:
            gc.unfreeze()
            self._gc_frozen = False

    def _raise_priority(self) -> None:
        """``SCHED_FIFO`` for the loop's thread (the run log is written by a process of its own,
        at normal priority)."""
        if self.rt_priority is None or not hasattr(os, "sched_setscheduler"):
            return
        detail: dict[str, Any] = {"policy": "SCHED_FIFO", "priority": self.rt_priority}
        try:
            previous = (os.sched_getscheduler(0), os.sched_getparam(0))
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.rt_priority))
            self._schedulers.append((0, previous))
            self.scheduler = f"SCHED_FIFO {self.rt_priority}"
        except OSError as error:
            detail = {"refused": str(error)}
            self.scheduler = f"default (SCHED_FIFO {self.rt_priority} refused: {error})"
            self._restore_priority()
        self._event("scheduler", detail)

    def _restore_priority(self) -> None:
        while self._schedulers:
            tid, (policy, param) = self._schedulers.pop()
            try:
                os.sched_setscheduler(tid, policy, param)
            except OSError:
                pass

    # --- the deploy loop --------------------------------------------------------------------
    def run(self, policy: Callable[[np.ndarray], np.ndarray] | None = None, seconds: float = 10.0) -> RunResult:
        """Start, run ``policy`` (None: zero actions) for ``seconds`` of control, shut down.
        Never raises: the outcome is in the :class:`RunResult`.

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
            while not done.is_set():
                try:
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

    # --- phases -----------------------------------------------------------------------------
    def _set_phase(self, phase: str) -> None:
        self.phase = phase
        t = self._now
        if phase in (SHUTDOWN, DAMPING) and self.stop_deadline is None and self.clock.realtime:
            # The watchdog takes over a stop that runs longer than its nominal length plus a margin
            # (paced runs: robot time follows the wall clock; an unpaced run may be slower than it).
            s, c = self.startup, self.safety
            nominal = (s.shutdown_time + s.off_delay if phase == SHUTDOWN else c.damping_time) + (s.exit_attempts + 2) * self.period
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
        if self.watchdog is None:
            timeout = self.safety.watchdog_periods * self.period
            if not self.clock.realtime:  # an unpaced run (rehearsal, test) may be descheduled for a while: not a stuck loop
                timeout = max(timeout, UNPACED_WATCHDOG)
            self.watchdog = LoopWatchdog(self, timeout, rt_priority=self.rt_priority).start()
        self._set_phase(ENABLE)
        self.armed = False
        report = self._special_frames(ENTER, s.enable_attempts, stop_on_fault=True)
        if self.fault is None and (report is None or not report.complete):
            missing = [self.description.joint_names[j] for j in np.flatnonzero(report.missing)] if report is not None else []
            self._fail(FaultKind.STARTUP, f"motors did not answer enter-motor-mode after {s.enable_attempts} tries: {missing}")
        if self.fault is not None:
            self._safe_stop()
            return
        self.robot.set_joint_impedance(self.damping)
        self.armed = True
        self._set_phase(SETTLE)
        self._run_for(s.settle_time, None)
        if self.fault is not None:
            self._safe_stop()
            return
        self.start_pose = q0 = self.robot.joint_positions()
        self._event("start_pose", {"q": q0})
        self._set_phase(RAMP)
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
        if self.fault is not None:
            self._safe_stop()
            return
        self._set_phase(RUNNING)

    def _shut_down(self) -> None:
        """Clean end: ramp the last command to damping, hold it, motors off."""
        s = self.startup
        self._set_phase(SHUTDOWN)
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
        self._set_phase(DAMPING)
        self._run_for(s.off_delay, None)
        self._motors_off()

    def _safe_stop(self) -> None:
        """After a fault: damping until ``damping_time`` after the detection, then motors off."""
        if self.phase == OFF:
            return
        self.armed = False
        self.robot.set_joint_impedance(self.damping)
        if self.phase != DAMPING:
            self._set_phase(DAMPING)
        until = self._stop_at if self._stop_at is not None else self._now + self.safety.damping_time
        self._run_for(until - self._now, None)
        self._motors_off()

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
        if self.phase == OFF:
            return
        report = self._special_frames(EXIT, self.startup.exit_attempts, stop_on_fault=False)
        # Motors that never confirmed it (a dead bus): left to their own timeout.
        missing = report.missing if report is not None else np.ones(self.description.dofs, dtype=bool)
        self.unconfirmed_off = tuple(self.description.joint_names[j] for j in np.flatnonzero(missing))
        if self._gc_was_enabled is not None:
            self._event("garbage_collection", {"young_collections": self.gc_collections, "longest_us": round(1e6 * self.gc_seconds_max, 1)})
        self._set_phase(OFF)
        self._event("motors_off", {"fault": None if self.fault is None else str(self.fault), "unconfirmed": list(self.unconfirmed_off)})

    def _run_for(self, seconds: float, compute: Callable[[], None] | None) -> None:
        """Cycles until ``seconds`` of robot time passed (skipped slots count: time is the
        deadline slot's, and advances every cycle, whatever the exchange did: this ends); stops
        early on a new fault unless already stopping."""
        stopping = self.phase in (DAMPING, SHUTDOWN)
        end = self._now + seconds - 0.5 * self.period
        while self._now < end:
            self._cycle(compute)
            if self.fault is not None and not stopping:
                return
            if self.fault is not None and compute is not None:
                compute = None  # a fault during the shutdown ramp: straight to damping
                self.robot.set_joint_impedance(self.damping)

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
                    self._fail(FaultKind.INTERNAL, f"safety check raised: {_describe(error)}")
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
            if log is not None:
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
        work, overrun = self.clock.done()
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
            self.faults.append(Fault(FaultKind.INTERNAL, f"run log failed, logging stopped: {_describe(error)}",
                                     max(0, self.robot.cycle - 1), self._now))  # fmt: skip

    def _log_cycle(self, report: CycleReport, sent: ImpedanceCommand, kind: str, imu: Any) -> None:
        log, robot, t = self.log, self.robot, report.time
        assert log is not None
        log.commands(report.cycle, t, self.phase, kind, sent.q_ref, sent.v_ref, sent.kp, sent.kd, sent.tau_ff)
        q, dq, tau = robot.measured
        log.replies(report.cycle, t, q, dq, tau, report.temperature, report.error_code,
                    report.missing, report.late, int(report.corrupt.sum()), report.unknown)  # fmt: skip
        if imu is not None or robot.latest_estimate is not None:
            log.estimator(report.cycle, t, imu, robot.latest_estimate)

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
            self._fail(FaultKind.INTERNAL, f"{what}: {_describe(error)}")
        else:
            self._fail(kind, f"{what}: {_describe(error)}")

    def _controller_failure(self) -> str | None:
        """Why the task's last controller tick fell back (infeasible QP, ...), or None."""
        check = getattr(self.task, "controller_failure", None)
        if check is None:
            return None
        try:
            return check()
        except Exception as error:  # noqa: BLE001
            return f"controller status unreadable: {_describe(error)}"

    def _driver_error_event(self, report: CycleReport) -> None:
        """Log a bus driver's first exception (per bus): the cause a bus-off or a missing reply needs."""
        names = self.supervisor.bus_names
        for b, error in enumerate(report.driver_errors):
            if error is not None and b not in self._driver_errors_seen:
                self._driver_errors_seen.add(b)
                sent = None if report.bus_sent is None else int(report.bus_sent[b])
                errors = None if report.bus_errors is None else int(report.bus_errors[b])
                self._event("driver_error", {"bus": names[b] if b < len(names) else b, "error": _describe(error),
                                             "sent": sent, "errors": errors})  # fmt: skip

    # --- the watchdog's way out ---------------------------------------------------------------
    def take_over(self, reason: str) -> bool:
        """Called by the watchdog from its own thread: abandon the loop and stop the motors without
        it (damping for ``damping_time``, then exit motor mode; see the module docstring).
        Returns False when there was nothing to do (motors already off, already taken over)."""
        with self._fault_lock:
            if self.phase in (IDLE, OFF) or self._abandoned:
                return False
            self._abandoned = True
        self._fail(FaultKind.WATCHDOG, reason)
        # A loop still cycling (a stop that overran) finishes its exchange first; one stuck in it does not.
        held = self._exchange_lock.acquire(timeout=2 * self.period)
        try:
            stop = EmergencyStop(self.robot, self.damping)
            self.emergency = stop.run(self._now, self.period, self.safety.damping_time, self.startup.exit_attempts,
                                      realtime=self.clock.realtime)  # fmt: skip
            self._now = self.emergency["time"]
        except Exception as error:  # noqa: BLE001 - whatever happens, the loop stays abandoned
            self.emergency = {"error": _describe(error)}
        finally:
            if held:
                self._exchange_lock.release()
        self.phase = OFF
        self.phase_times.setdefault(OFF, self._now)
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

    # --- helpers ----------------------------------------------------------------------------
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


def robot_faults(supervisor: SafetySupervisor, robot: CanRobot, report: CycleReport) -> list[Fault]:
    """The supervisor's faults for the robot's current measurements."""
    q, dq, tau = robot.measured
    return supervisor.check(report, q, dq, tau, robot.latest_imu)


def _describe(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"


__all__ = [
    "PROFILES",
    "Controller",
    "DeadlineClock",
    "RealtimeRuntime",
    "LoopAbandoned",
    "RunResult",
    "StandingTask",
    "StartupConfig",
    "TimingStats",
    "cosine",
    "exit_code_for",
    "min_jerk",
]
