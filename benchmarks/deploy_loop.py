"""The real-time deploy loop over the emulated CAN buses (or, ``--transport dds``, the G1's DDS interface), all 29 G1 joints (one JSON object).

For each control rate (500 Hz for 60 s and 1 kHz for 10 s by default): the actuator emulator, the
CAN robot, the real-time runtime paced by absolute deadlines under ``SCHED_FIFO`` (as granted: see
``scheduler``), a controller (joint-PD hold by default, ``--controller wbc`` for the QP balance
controller with the estimator, what ``giwbc deploy`` runs; ``--controller walk``: the walking WBC
walking forward at ``--vx`` after 0.5 s of standing; several controllers alternate in one run, for
a comparison on the same machine state) and the MCAP run log, as ``giwbc deploy --emulate`` runs
them. Measured over the running phase only:

- period error |start_k - start_(k-1) - T| and lateness (start - deadline): p50 / p99 / max, us;
- overruns (a cycle's work ending after the next deadline) and skipped slots, and why each overrun
  happened: ``late_start`` (the loop woke more than a quarter period late: the thread was not
  running) or ``long_work`` (its work took too long), and among those ``cpu_short`` (the thread's
  CPU time fell 20 % or more short of the wall time, with no context switch: time the hypervisor
  took); ``steal_ms``: CPU time the kernel saw stolen by the hypervisor during the phase, per CPU;
- host work per cycle (wall time of the loop's own work, from the cycle's start to its next command
  computed: mean and p50 / p99; with the lockstep emulator it includes the emulator's physics; the
  cycle's run-log records are built after it, in the rest of the period, and show as lateness when
  they overflow it);
- CPU time per cycle (thread time), the host's CAN path alone (drain, encode, send, receive,
  decode, IMU, estimator) and the host's CPU time per CAN frame (one command plus one reply per
  motor and cycle); the emulator's CPU time (its own process, or the loop's thread in lockstep);
- the bus loads of the hardware plan at that rate; ``emulator_stalls``: how late the emulator
  process ran after a physics step was due (the machine not giving it a CPU shows there);
- ``work_parts``: the host work split by part, wall time per cycle (p50 / p99 / mean, us): the CAN
  exchange (and inside it ``receive``: reading every bus, decoding the replies and the joint state;
  ``encode``: the commands' frames; ``send``: writing them; ``exchange_other``: the rest of it, the
  IMU and the cycle's report; over DDS ``receive`` takes and checks the states and ``send`` fills
  and publishes the command), the estimator, the safety check, the controller's tick (for the
  walker also its WBC tick and its own planning), and the rest (the runtime's bookkeeping); and each part's mean over
  the slowest 1 % of cycles against its mean over all (``slowest_1pct.ratio_to_all_cycles``):
  every part slower at once in those cycles is the machine, not one code path;
- with ``--controller walk``, ``walking.contact_switches``: how many of the slowest 1 % of cycles
  are contact-switch cycles (the walker's tick where its phase or stance changed, and the next one:
  a lift-off or touch-down plans and changes the WBC's contacts and tasks), and the host work p99
  of the other cycles (recording the walker's phase costs its tick about a microsecond).

``--emulator process`` (default): the emulator runs in its own process on ``giwbc-unix`` channels
(as motors run on their own hardware), on its own real-time clock and its own CPU; the CAN robot
reads each cycle's replies at the next cycle. The loop's thread has the first CPU to itself: the
emulator and the run logger run on the others. ``--emulator lockstep``: in the loop's thread on
python-can ``virtual`` buses. The emulator shares this machine with the loop, so a stall of its
CPU looks like silent motors: the benchmark tolerates 25 silent cycles (``max_missing_cycles``)
where a deployment stops after 3, and reports the cycles with missing replies. ``--repeat N``
runs each rate N times.

The run log carries the 3D scene (link transforms, joint states, contact forces) at ``--scene-rate``
Hz, computed in the logger's process, as ``giwbc deploy`` writes it. ``--foxglove``: each run twice,
alternately: ``before`` (the log without the scene) and ``after`` (the scene in the log and streamed
live from the logger's process to a Foxglove viewer connected over loopback, in a process of its own);
``foxglove_effect`` gives overruns and p99 period error of both, per rate (medians over ``--repeat``).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import giwbc  # noqa: E402,F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
import numpy as np  # noqa: E402

from giwbc.apps.deploy import make_controller, scene_channels  # noqa: E402
from giwbc.apps.deploy_setup import walking_hold  # noqa: E402
from giwbc.apps.deploy_walk import WalkCommand  # noqa: E402
from giwbc.estimation.estimated_robot import EstimatedRobot  # noqa: E402
from giwbc.estimation.estimator import StateEstimator  # noqa: E402
from giwbc.hal.can_robot import CanRobot  # noqa: E402
from giwbc.emulation import ActuatorEmulator, EmulatorConfig  # noqa: E402
from giwbc.emulation.dds_emulator import DdsEmulatorProcess  # noqa: E402
from giwbc.hal.dds.robot import DdsRobot  # noqa: E402
from giwbc.emulation.process import EmulatorProcess  # noqa: E402
from giwbc.hal.hardware import load_hardware  # noqa: E402
from giwbc.apps.deploy_walk_log import WalkerRecorder  # noqa: E402
from giwbc.runlog import RunLogWriter  # noqa: E402
from giwbc.hal.safety import SafetyConfig  # noqa: E402
from giwbc.robot import load  # noqa: E402
from giwbc.runtimes.phases import StartupConfig  # noqa: E402
from giwbc.runtimes.realtime import RealtimeRuntime  # noqa: E402
from giwbc.tasks.standing import StandingTask  # noqa: E402

BENCHMARK_SAFETY = SafetyConfig(max_missing_cycles=25, imu_timeout_cycles=50)


def _time_calls(owner: object, name: str, clock, totals: dict[str, float], key: str) -> None:
    """Replace ``owner.name`` by a wrapper adding each call's ``clock()`` seconds to ``totals[key]``."""
    method = getattr(owner, name)

    def timed(*args, **kwargs):
        start = clock()
        try:
            return method(*args, **kwargs)
        finally:
            totals[key] += clock() - start

    setattr(owner, name, timed)


class _CpuMeter:
    """Thread CPU time spent inside the emulator's calls and inside the robot's exchanges (with the
    estimator's update after each, when there is one: the host's CAN path)."""

    def __init__(self, emulator: ActuatorEmulator | None, robot: CanRobot, estimated: EstimatedRobot | None = None) -> None:
        self.seconds = {"emulator": 0.0, "exchange": 0.0}  # emulator (in this thread: lockstep only); exchanges, emulator included
        for name in ("advance", "answer") if emulator is not None else ():
            _time_calls(emulator, name, time.thread_time, self.seconds, "emulator")
        _time_calls(robot, "exchange", time.thread_time, self.seconds, "exchange")
        if estimated is not None:
            _time_calls(estimated, "update", time.thread_time, self.seconds, "exchange")

    @property
    def total(self) -> float:
        return self.seconds["emulator"]

    @property
    def exchange(self) -> float:
        return self.seconds["exchange"]


class _WallParts:
    """Wall time of each part of every cycle's work, recorded at the clock's ``done`` (one row per
    cycle, aligned with the clock's stats): the CAN exchange, the estimator's update, the safety
    check, the controller's tick (``controller``) and, for the walker, its WBC tick (``wbc``, inside
    ``controller``: the rest of it is the walker's own planning). ``rest`` is the cycle's work less
    the parts (the runtime's own: report, signals, fault bookkeeping). Each wrapper costs about
    0.2 µs."""

    PARTS = ("exchange", "estimator", "safety", "controller", "wbc", "receive", "encode", "send")
    SUBPARTS = ("wbc", "receive", "encode", "send")  # inside another part (the controller's, the exchange's)

    def __init__(self) -> None:
        self._now = dict.fromkeys(self.PARTS, 0.0)
        self.rows: list[tuple[float, ...]] = []

    def wrap(self, owner: object, name: str, part: str) -> None:
        _time_calls(owner, name, time.perf_counter, self._now, part)

    def attach(self, clock) -> None:
        """Count the parts from each cycle's start (work between cycles, such as the controller's
        first tick at the hand-over, is not a cycle's) and record a row when ``clock`` ends its work."""
        begin, done, now = clock._begin, clock.done, self._now

        def started(*args) -> None:
            for part in self.PARTS:
                now[part] = 0.0
            begin(*args)

        def recorded() -> tuple[float, bool]:
            result = done()
            self.rows.append(tuple(now[part] for part in self.PARTS))
            return result

        clock._begin = started
        clock.done = recorded

    def summary(self, work: list[float], first: int, last: int | None) -> dict[str, object]:
        """p50 / p99 / mean (µs) of each part over the cycles ``first:last``; and each part's mean
        over the slowest 1 % of those cycles by work against its mean over all of them (``slowest_1pct``):
        one part far above its mean points at a code path, every part above it at once at the machine."""
        parts = 1e6 * np.asarray(self.rows[first:last], dtype=float).reshape(-1, len(self.PARTS))
        work_us = 1e6 * np.asarray(work, dtype=float)
        n = min(len(parts), len(work_us))
        if not n:
            return {}
        parts, work_us = parts[:n], work_us[:n]
        table = {name: parts[:, k] for k, name in enumerate(self.PARTS)}
        for name in self.SUBPARTS:
            if not table[name].any():
                del table[name]
        if "wbc" in table:
            table["planning"] = table["controller"] - table["wbc"]  # the walker's own work
        if "receive" in table and "send" in table:
            table["exchange_other"] = table["exchange"] - table["receive"] - table.get("encode", 0.0) - table["send"]
        table["rest"] = work_us - sum(table[name] for name in ("exchange", "estimator", "safety", "controller"))  # (sub-parts: inside these)
        slowest = np.argsort(work_us)[n - max(1, n // 100):]

        def stats(values: np.ndarray) -> dict[str, float]:
            return {"p50": round(float(np.median(values)), 1), "p99": round(float(np.percentile(values, 99)), 1), "mean": round(float(values.mean()), 1)}

        return {
            "parts_us": {name: stats(values) for name, values in table.items()},
            "slowest_1pct": {
                "cycles": len(slowest), "work_mean_us": round(float(work_us[slowest].mean()), 1),
                "part_mean_us": {name: round(float(values[slowest].mean()), 1) for name, values in table.items()},
                "ratio_to_all_cycles": {name: round(float(values[slowest].mean() / values.mean()), 2) for name, values in table.items() if values.mean() > 0},
            },
            "clock": "time.perf_counter, wall",
        }


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (Linux ``/proc/<pid>/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _steal_seconds() -> dict[str, float]:
    """Per CPU, time stolen by the hypervisor so far (``/proc/stat``; empty where not reported)."""
    try:
        lines = Path("/proc/stat").read_text().splitlines()
    except OSError:
        return {}
    tick = os.sysconf("SC_CLK_TCK")
    return {f[0]: int(f[8]) / tick for f in (line.split() for line in lines) if f[0].startswith("cpu") and f[0] != "cpu" and len(f) > 8}


def _overrun_causes(stats, period: float) -> dict[str, int]:
    """Why each overrun happened (see the module docstring)."""
    # A cycle that began but never reached the clock's done() (the run stopped inside it) has a
    # lateness and no work: the cycles that ended only.
    n = min(len(stats.lateness), len(stats.work), len(stats.cpu), len(stats.overrun))
    late = np.asarray(stats.lateness[:n])
    work = np.asarray(stats.work[:n])
    cpu = np.asarray(stats.cpu[:n])
    over = np.asarray(stats.overrun[:n], dtype=bool)
    late_start = over & (late > 0.25 * period)
    long_work = over & ~late_start
    return {
        "late_start": int(late_start.sum()),
        "long_work": int(long_work.sum()),
        "long_work_cpu_short": int((long_work & (cpu < 0.8 * work)).sum()),
    }


def _switch_share(work: list[float], phases: dict[int, tuple[object, object]], first: int) -> dict[str, object]:
    """Host work at the walker's contact switches: the tick whose phase (or stance) changed (a
    lift-off or a touch-down: the walker plans, the WBC's contacts and tasks change) and the one
    after it, against the others: how many of the slowest 1 % of cycles are switch cycles, and the
    p99 of the other cycles."""
    work_us = 1e6 * np.asarray(work)
    switch = np.zeros(len(work_us), dtype=bool)
    for k in range(len(work_us)):
        now, before = phases.get(first + k), phases.get(first + k - 1)
        if now is not None and before is not None and now != before:
            switch[k : k + 2] = True
    slowest = np.argsort(work_us)[len(work_us) - max(1, len(work_us) // 100):] if len(work_us) else np.zeros(0, dtype=int)
    return {
        "switch_cycles": int(switch.sum()),
        "slowest_1pct": len(slowest),
        "slowest_1pct_at_switches": int(switch[slowest].sum()),
        "work_p99_us_without_switch_cycles": float(np.percentile(work_us[~switch], 99)) if (~switch).any() else None,
        "work_mean_us_switch_cycles": float(work_us[switch].mean()) if switch.any() else None,
    }


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def run_rate(description, model, rate: float, seconds: float, controller: str, log_dir: Path, log: bool, rt_priority: int | None,
             mode: str, pin: bool, scene_rate: float = 50.0, live: bool = False, vx: float = 0.3,
             cpu_latency: float | None = None, transport: str = "can", spin: float | None = None) -> dict:  # fmt: skip
    plan = load_hardware(description.folder / "hardware.toml", rate, joint_names=description.joint_names, interface="virtual")
    cpus = sorted(os.sched_getaffinity(0))
    split = pin and len(cpus) > 1  # the emulator on the last CPU, the loop's thread on the first
    if transport == "dds":  # the G1's low-level DDS interface (rt/lowcmd, rt/lowstate) on loopback; the emulator in its own process
        dds_plan = load_hardware(description.folder / "hardware_dds.toml", rate, joint_names=description.joint_names, allow_dds=True)
        emulator = DdsEmulatorProcess(dds_plan, plan, description, EmulatorConfig(), cpu=cpus[-1] if split else None)
        can_robot = DdsRobot(description, emulator.host_plan())
        mode = "process"
    elif mode == "process":
        emulator = EmulatorProcess(plan, description, EmulatorConfig(), rt_priority=None if rt_priority is None else max(1, rt_priority - 1),
                                   cpu=cpus[-1] if split else None)  # fmt: skip
        can_robot = CanRobot(description, emulator.host_plan(), imu=emulator.imu_channel, wait_for_replies=False)
    else:
        emulator = ActuatorEmulator(plan, description, EmulatorConfig(), model=copy.copy(model))
        can_robot = CanRobot(description, emulator.host_plan(), imu=emulator.imu_channel, peer=emulator)
    # The WBC needs a base state: giwbc deploy's EstimatedRobot(CanRobot(...)).
    robot = EstimatedRobot(can_robot, StateEstimator(description)) if controller in ("wbc", "walk") else can_robot
    meter = _CpuMeter(emulator if mode == "lockstep" else None, can_robot, robot if robot is not can_robot else None)
    walk = WalkCommand(vx=vx) if controller == "walk" else None
    task = StandingTask(make_controller(controller, description, walk), description.default_positions)
    hold = walking_hold(task)
    recorders = () if hold is None else (WalkerRecorder(hold.walker),)  # as giwbc deploy: the walker's state in the log
    port = _free_port() if live else None
    scene = scene_channels(description, description.joint_names, scene_rate, port)
    writer = RunLogWriter(log_dir / f"deploy_loop_{int(rate)}.mcap", description.joint_names, {"benchmark": "deploy_loop"},
                          cpus=cpus[1:] if split else None, extension=scene, channels=[r.channel for r in recorders]) if log else None  # off the loop's CPU  # fmt: skip
    viewer = None
    if live and writer is not None:  # a Foxglove viewer on loopback, in a process of its own (not this one's CPU time)
        viewer = subprocess.Popen([sys.executable, "-m", "giwbc.apps.live", str(port), str(seconds + 30.0)],
                                  stdout=subprocess.PIPE, text=True)  # fmt: skip
    runtime = RealtimeRuntime(task, robot, controller_rate=rate, log=writer, rt_priority=rt_priority, cpu_latency=cpu_latency,
                              safety=BENCHMARK_SAFETY, recorders=recorders, spin=spin,
                              startup=StartupConfig(settle_time=0.05, ramp_time=0.5, shutdown_time=0.1, off_delay=0.05))  # fmt: skip
    parts = _WallParts()  # (wraps the meter's wrappers: the same calls)
    parts.wrap(can_robot, "exchange", "exchange")
    if transport == "dds":  # inside the exchange: take and check the states, fill and publish the command
        parts.wrap(can_robot, "_take_states", "receive")
        parts.wrap(can_robot, "_publish", "send")
    else:  # inside the exchange: the replies (read, decode, joint state), the commands' frames, their writes
        parts.wrap(can_robot, "_collect", "receive")
        parts.wrap(can_robot, "_frames", "encode")
        parts.wrap(can_robot.ports, "send", "send")
    if robot is not can_robot:
        parts.wrap(robot, "update", "estimator")
    parts.wrap(runtime.supervisor, "check", "safety")
    parts.wrap(task, "apply_command", "controller")
    if hold is not None:
        parts.wrap(hold.walker.wbc, "update", "wbc")
    parts.attach(runtime.clock)
    phases: dict[int, tuple[object, object]] = {}  # the walker's (phase, stance) after each tick, by the cycle's index in the clock's stats
    if hold is not None:
        apply = task.apply_command

        def recorded_apply() -> None:
            apply()
            state = hold.walker.state
            phases[len(runtime.clock.stats.work)] = (state.phase, state.stance)

        task.apply_command = recorded_apply  # type: ignore[method-assign]
    marks: dict[str, dict[str, object]] = {}
    original = runtime._set_phase

    def mark(phase: str) -> None:
        marks.setdefault(phase, {
            "emulator": meter.total, "exchange": meter.exchange, "steal": _steal_seconds(),
            "child": _cpu_seconds(emulator.pid) if mode == "process" and emulator.pid is not None else math.nan,
            "logger": _cpu_seconds(writer.pid) if writer is not None and writer.pid is not None else math.nan,
        })  # fmt: skip
        original(phase)

    runtime._set_phase = mark  # type: ignore[method-assign]
    if split:
        os.sched_setaffinity(0, {cpus[0]})  # this thread only
    result = runtime.run(None, seconds)
    if split:
        os.sched_setaffinity(0, set(cpus))
    can_robot.close()
    emulator.close()
    if writer is not None:
        writer.close()
    received = None
    if viewer is not None:
        out, _ = viewer.communicate(timeout=60)  # the server stopped with the log: the viewer leaves
        received = json.loads(out.strip().splitlines()[-1]) if out.strip() else {}
    first, last = runtime.phase_cycles.get("running"), runtime.phase_cycles.get("shutdown")
    stats = runtime.clock.stats.between(first if first is not None else 0, last)
    period = 1.0 / rate
    summary = stats.summary(period)
    cycles = max(1, summary["cycles"])
    start, end = marks.get("running", {}), marks.get("shutdown", {})

    def per_cycle(key: str) -> float:
        return (float(end.get(key, math.nan)) - float(start.get(key, math.nan))) / cycles  # type: ignore[arg-type]

    emulator_cpu = per_cycle("emulator") if mode == "lockstep" else per_cycle("child")
    exchange_cpu = per_cycle("exchange") - (emulator_cpu if mode == "lockstep" else 0.0)
    total_cpu = float(np.mean(stats.cpu)) if stats.cpu else float("nan")
    host_cpu = total_cpu - (emulator_cpu if mode == "lockstep" else 0.0)
    steal_start, steal_end = start.get("steal", {}), end.get("steal", {})
    frames = 2 * len(plan.motors) if transport == "can" else 2  # DDS: one LowCmd_ and one LowState_ per cycle
    loads = list(plan.loads.values()) if transport == "can" else []
    walking = None
    if controller == "walk":
        truth = emulator.truth_between(runtime.phase_times.get("running", 0.0), runtime.phase_times.get("shutdown", math.inf))
        walking = {"vx": vx, "steps": task.controller.steps,
                   "dx_m": float(truth[-1, 3] - truth[0, 3]) if len(truth) else None,
                   "max_tilt_deg": float(np.degrees(truth[:, 2].max())) if len(truth) else None,
                   "contact_switches": _switch_share(stats.work, phases, first if first is not None else 0)}  # fmt: skip
    return {
        "transport": transport,
        "controller": controller,
        "walking": walking,
        "rate_hz": rate,
        "seconds": seconds,
        "scheduler": runtime.scheduler,
        "cpu_latency_us": cpu_latency,
        "spin_us": None if spin is None else 1e6 * spin,
        "cpu_idle": runtime.cpu_idle,
        "emulator_scheduler": emulator.scheduler if mode == "process" else "the loop's thread",
        # how late the emulator process ran after a physics step was due (EmulatorStalls; CAN process mode)
        "emulator_stalls": None if getattr(emulator, "stalls", None) is None else {
            "longest_ms": round(1e3 * emulator.stalls.longest, 3), "at_s": round(emulator.stalls.at, 3),
            "over_period": emulator.stalls.over_period},
        "ok": result.ok,
        "fault": None if result.fault is None else str(result.fault),
        "cycles": summary["cycles"],
        "period_error_us": summary["period_error_us"],
        "lateness_us": summary["lateness_us"],
        "work_us": summary["work_us"],
        "work_mean_us": 1e6 * float(np.mean(stats.work)) if len(stats.work) else None,
        "work_parts": parts.summary(stats.work, first if first is not None else 0, last),
        "overruns": summary["overruns"],
        "skipped_slots": summary["skipped_slots"],
        "overrun_causes": _overrun_causes(stats, period),
        "steal_ms": {cpu: round(1e3 * (steal_end[cpu] - steal_start[cpu]), 1) for cpu in steal_end if cpu in steal_start},  # type: ignore[index, operator]
        "cpu_per_cycle_us": {
            "host_mean": 1e6 * host_cpu,
            "host_p50": summary["cpu_us"]["p50"] if mode == "process" else None,
            "host_p99": summary["cpu_us"]["p99"] if mode == "process" else None,
            "host_can_path_mean": 1e6 * exchange_cpu,
            "emulator_mean": 1e6 * emulator_cpu,
            "emulator_in_loop_thread": mode == "lockstep",
            "logger_process_mean": 1e6 * per_cycle("logger"),
        },
        "host_cpu_per_frame_us": {"can_path": 1e6 * exchange_cpu / frames, "whole_cycle": 1e6 * host_cpu / frames},
        "frames_per_cycle": frames,
        "log_records_dropped": None if writer is None else writer.dropped,
        "scene": {"log_hz": scene_rate if writer is not None and scene_rate > 0 else 0, "live": live, "viewer_received": received},
        "bus_load": None if not loads else {
            "buses": len(loads),
            "max_nominal_pct": round(100 * max(b.nominal for b in loads), 1),
            "max_worst_case_pct": round(100 * max(b.worst_case for b in loads), 1),
            "per_bus_nominal_pct": {b.bus: round(100 * b.nominal, 1) for b in loads},
        },
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robot", default="g1")
    parser.add_argument("--rates", type=float, nargs="+", default=[500.0, 1000.0])
    parser.add_argument("--seconds", type=float, nargs="+", default=[60.0, 10.0],
                        help="seconds of control per rate (one value, or one per rate; the issue asks 60 s at 500 Hz)")
    parser.add_argument("--repeat", type=int, default=1, help="runs per rate")
    parser.add_argument("--controller", choices=("pd", "wbc", "walk"), nargs="+", default=["pd"],
                        help="one or more: several alternate run by run (compared on the same machine state)")
    parser.add_argument("--vx", type=float, default=0.3, help="the walk controller's forward command, m/s")
    parser.add_argument("--no-log", action="store_true", help="run without the MCAP log")
    parser.add_argument("--scene-rate", type=float, default=50.0, help="Hz of the 3D scene in the log (0: none)")
    parser.add_argument("--foxglove", action="store_true",
                        help="each run before (log without the scene) and after (scene logged and streamed live to a viewer)")
    parser.add_argument("--rt-priority", type=int, default=50,
                        help="SCHED_FIFO priority of the loop (the emulator process gets one less); 0: the default scheduler")
    parser.add_argument("--cpu-latency", type=float, nargs="+", default=[None], metavar="US",
                        help="hold the CPUs' wake-up latency at most US µs while the motors are on (PM QoS, as giwbc deploy "
                             "--cpu-latency; 0: idle CPUs poll); several values (-1: none) alternate run by run")
    parser.add_argument("--spin", type=float, default=None, metavar="US",
                        help="µs the loop spins before each deadline instead of sleeping (default: the runtime's, 100 under SCHED_FIFO); "
                             "a spin as long as the slack keeps the loop's CPU, and its caches, from other processes (the clock still "
                             "sleeps 6 %% of each period under SCHED_FIFO)")
    parser.add_argument("--no-pin", action="store_true", help="do not pin the loop's thread and the emulator process to different CPUs")
    parser.add_argument("--transport", choices=("can", "dds"), nargs="+", default=["can"],
                        help="can: the emulated CAN buses; dds: the G1's rt/lowcmd / rt/lowstate on loopback (emulator in its own process); "
                             "both alternate in one run")  # fmt: skip
    parser.add_argument("--emulator", choices=("process", "lockstep"), default="process",
                        help="the emulator in its own process on giwbc-unix channels (as motors on their own hardware), "
                             "or in the loop's thread on python-can virtual buses (lockstep)")
    args = parser.parse_args()
    seconds = args.seconds if len(args.seconds) == len(args.rates) else [args.seconds[0]] * len(args.rates)
    latencies = [None if value is None or value < 0 else value for value in args.cpu_latency]

    description = load(args.robot)
    model = description.build_mujoco()
    load_before = os.getloadavg()
    results = []
    variants = [("before", 0.0, False), ("after", args.scene_rate or 50.0, True)] if args.foxglove else [("", args.scene_rate, False)]
    with tempfile.TemporaryDirectory() as tmp:
        for rate, duration in zip(args.rates, seconds):
            for _ in range(max(1, args.repeat)):
                for controller in args.controller:
                    for latency in latencies:
                        for name, scene_rate, live in variants:  # alternated: slow drifts of the machine hit both
                            for transport in args.transport:
                                result = run_rate(description, model, rate, duration, controller, Path(tmp), not args.no_log,
                                                  args.rt_priority or None, args.emulator, not args.no_pin, scene_rate, live, args.vx,
                                                  latency, transport, None if args.spin is None else 1e-6 * args.spin)  # fmt: skip
                                results.append({"variant": name, **result} if name else result)
    effect = None
    if args.foxglove:
        effect = {
            f"{rate:g}": {
                key: {name: float(np.median([pick(r) for r in results if r["rate_hz"] == rate and r["variant"] == name]))
                      for name in ("before", "after")}
                for key, pick in (("overruns", lambda r: r["overruns"]), ("p99_period_error_us", lambda r: r["period_error_us"]["p99"]),
                                  ("logger_cpu_per_cycle_us", lambda r: r["cpu_per_cycle_us"]["logger_process_mean"]))
            }
            for rate in args.rates
        }  # fmt: skip
    print(json.dumps({
        "benchmark": "deploy_loop",
        "robot": args.robot,
        "joints": description.dofs,
        "controller": args.controller[0] if len(args.controller) == 1 else args.controller,
        "work_by_controller_us": {
            f"{rate:g}": {c: {"mean": float(np.median([r["work_mean_us"] for r in results if r["rate_hz"] == rate and r["controller"] == c])),
                              "p99": float(np.median([r["work_us"]["p99"] for r in results if r["rate_hz"] == rate and r["controller"] == c]))}
                          for c in args.controller}
            for rate in args.rates
        },  # medians over --repeat
        "work_by_cpu_latency_us": None if len(latencies) < 2 else {
            f"{rate:g}": {c: {"none" if lat is None else f"{lat:g}": {
                key: float(np.median([pick(r) for r in results if r["rate_hz"] == rate and r["controller"] == c and r["cpu_latency_us"] == lat]))
                for key, pick in (("p50", lambda r: r["work_us"]["p50"]), ("p99", lambda r: r["work_us"]["p99"]), ("overruns", lambda r: r["overruns"]))}
                for lat in latencies} for c in args.controller}
            for rate in args.rates
        },  # medians over --repeat of runs alternated with each other
        "exchange_by_transport_us": {  # the host's exchange (and estimator update) CPU time per cycle, medians over --repeat
            f"{rate:g}": {t: float(np.nanmedian([r["cpu_per_cycle_us"]["host_can_path_mean"] for r in results if r["rate_hz"] == rate
                                                 and r["transport"] == t])) for t in args.transport}  # (a run stopped early: NaN, left out)
            for rate in args.rates
        },
        "log": not args.no_log,
        "transport": ("giwbc-unix channels (AF_UNIX SOCK_SEQPACKET), emulator in its own process" if args.emulator == "process"
                      else "python-can virtual, emulator in the loop thread (lockstep)"),
        "machine": {"cpus": os.cpu_count(), "loadavg_before": [round(x, 2) for x in load_before],
                    "loadavg_after": [round(x, 2) for x in os.getloadavg()], "python": sys.version.split()[0]},
        "foxglove_effect": effect,
        "results": results,
    }))  # fmt: skip


if __name__ == "__main__":
    main()
