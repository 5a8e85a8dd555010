"""The real-time deploy loop over the emulated CAN buses, all 29 G1 joints (one JSON object).

For each control rate (500 Hz and 1 kHz by default): the actuator emulator on python-can ``virtual``
buses, the CAN robot, the real-time runtime paced by absolute deadlines, a controller (joint-PD
hold by default, ``--controller wbc`` for the QP balance controller with the estimator) and the
MCAP run log, as ``giwbc deploy --emulate`` runs them. Measured over the running phase only:

- period error |start_k - start_(k-1) - T| and lateness (start - deadline): p50 / p99 / max, us;
- overruns (work ending after the next deadline) and skipped slots;
- CPU time per cycle (thread time), split into the host's part and the emulator's part (which a
  real deployment does not pay), the host's CAN path alone (drain, encode, send, receive, decode),
  and the host's CPU time per CAN frame (one command plus one reply per motor and cycle);
- the bus loads of the hardware plan at that rate.

``--emulator process`` (default): the emulator runs in its own process on ``giwbc-unix`` channels
(as motors run on their own hardware), on its own real-time clock; the CAN robot then reads each
cycle's replies at the next cycle instead of waiting for them (``wait_for_replies=False``), and the
emulator's CPU time is its process's (``emulator_mean``), not the loop's. ``--emulator lockstep``:
the emulator in the loop's thread on python-can ``virtual`` buses; its CPU time is in every cycle.
Other processes share this machine's cores; the load average is reported with the results.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from giwbc.deploy import make_controller  # noqa: E402
from giwbc.hal.can_robot import CanRobot  # noqa: E402
from giwbc.hal.emulator import ActuatorEmulator, EmulatorConfig  # noqa: E402
from giwbc.hal.emulator_process import EmulatorProcess  # noqa: E402
from giwbc.hal.hardware import load_hardware  # noqa: E402
from giwbc.hal.runlog import RunLogWriter  # noqa: E402
from giwbc.robot import load  # noqa: E402
from giwbc.runtimes.realtime import RealtimeRuntime, StandingTask, StartupConfig  # noqa: E402


class _CpuMeter:
    """Thread CPU time spent inside the emulator's calls and inside the robot's exchanges."""

    def __init__(self, emulator: ActuatorEmulator | None, robot: CanRobot) -> None:
        self.total = 0.0  # emulator (in this thread: lockstep only)
        self.exchange = 0.0  # exchanges, emulator included
        for name in ("advance", "answer") if emulator is not None else ():
            method = getattr(emulator, name)

            def timed(now: float, method=method) -> None:
                start = time.thread_time()
                method(now)
                self.total += time.thread_time() - start

            setattr(emulator, name, timed)
        exchange = robot.exchange

        def timed_exchange(*args, **kwargs):
            start = time.thread_time()
            try:
                return exchange(*args, **kwargs)
            finally:
                self.exchange += time.thread_time() - start

        robot.exchange = timed_exchange  # type: ignore[method-assign]


def _child_cpu_seconds(pid: int) -> float:
    """User + system CPU time of another process so far (Linux ``/proc/<pid>/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_rate(description, model, rate: float, seconds: float, controller: str, log_dir: Path, log: bool, rt_priority: int | None,
             mode: str, pin: bool) -> dict:  # fmt: skip
    plan = load_hardware(description.folder / "hardware.toml", rate, joint_names=description.joint_names, interface="virtual")
    estimator = None
    if controller == "wbc":
        from giwbc.robot.estimator import StateEstimator

        estimator = StateEstimator(description)
    if mode == "process":
        cpus = sorted(os.sched_getaffinity(0))
        split = pin and len(cpus) > 1  # the emulator on the last CPU, the loop's thread on the first
        emulator = EmulatorProcess(plan, description, EmulatorConfig(), rt_priority=None if rt_priority is None else max(1, rt_priority - 1),
                                   cpu=cpus[-1] if split else None)  # fmt: skip
        robot = CanRobot(description, emulator.host_plan(), imu=emulator.imu_channel, estimator=estimator, wait_for_replies=False)
    else:
        emulator = ActuatorEmulator(plan, description, EmulatorConfig(), model=copy.copy(model))
        robot = CanRobot(description, emulator.host_plan(), imu=emulator.imu_channel, peer=emulator, estimator=estimator)
    meter = _CpuMeter(emulator if mode == "lockstep" else None, robot)
    task = StandingTask(make_controller(controller, description), description.default_positions)
    writer = RunLogWriter(log_dir / f"deploy_loop_{int(rate)}.mcap", description.joint_names, {"benchmark": "deploy_loop"}) if log else None
    runtime = RealtimeRuntime(task, robot, controller_rate=rate, log=writer, rt_priority=rt_priority,
                              startup=StartupConfig(settle_time=0.05, ramp_time=0.5, shutdown_time=0.1, off_delay=0.05))  # fmt: skip
    emulator_cpu_at: dict[str, float] = {}
    exchange_cpu_at: dict[str, float] = {}
    original = runtime._set_phase

    child_cpu_at: dict[str, float] = {}

    def mark(phase: str) -> None:
        emulator_cpu_at.setdefault(phase, meter.total)
        exchange_cpu_at.setdefault(phase, meter.exchange)
        if mode == "process" and emulator.pid is not None:
            child_cpu_at.setdefault(phase, _child_cpu_seconds(emulator.pid))
        original(phase)

    runtime._set_phase = mark  # type: ignore[method-assign]
    if mode == "process" and split:
        os.sched_setaffinity(0, {cpus[0]})  # this thread only (the log writer's thread may run anywhere)
    result = runtime.run(None, seconds)
    if mode == "process" and split:
        os.sched_setaffinity(0, set(cpus))
    robot.close()
    emulator.close()
    if writer is not None:
        writer.close()
    first, last = runtime.phase_cycles.get("running"), runtime.phase_cycles.get("shutdown")
    stats = runtime.clock.stats.between(first if first is not None else 0, last)
    period = 1.0 / rate
    summary = stats.summary(period)
    cycles = max(1, summary["cycles"])
    emulator_cpu = (emulator_cpu_at.get("shutdown", meter.total) - emulator_cpu_at.get("running", 0.0)) / cycles
    exchange_cpu = (exchange_cpu_at.get("shutdown", meter.exchange) - exchange_cpu_at.get("running", 0.0)) / cycles
    can_path = exchange_cpu - emulator_cpu  # the host's CAN path: drain, encode, send, receive, decode, IMU
    if mode == "process":  # the emulator's CPU is its own process's, not this thread's
        child_cpu = (child_cpu_at.get("shutdown", math.nan) - child_cpu_at.get("running", math.nan)) / cycles
    total_cpu = float(np.mean(stats.cpu)) if stats.cpu else float("nan")
    frames = 2 * len(plan.motors)
    loads = list(plan.loads.values())
    return {
        "rate_hz": rate,
        "seconds": seconds,
        "emulator_scheduler": emulator.scheduler if mode == "process" else "the loop's thread",
        "ok": result.ok,
        "fault": None if result.fault is None else str(result.fault),
        "cycles": summary["cycles"],
        "period_error_us": summary["period_error_us"],
        "lateness_us": summary["lateness_us"],
        "work_us": summary["work_us"],
        "overruns": summary["overruns"],
        "skipped_slots": summary["skipped_slots"],
        "cpu_per_cycle_us": {
            "total_mean": 1e6 * total_cpu,
            "total_p50": summary["cpu_us"]["p50"],
            "total_p99": summary["cpu_us"]["p99"],
            "emulator_mean": 1e6 * (emulator_cpu if mode == "lockstep" else child_cpu),
            "emulator_in_loop_thread": mode == "lockstep",
            "host_mean": 1e6 * (total_cpu - emulator_cpu),
            "host_can_path_mean": 1e6 * can_path,
        },
        "host_cpu_per_frame_us": {"can_path": 1e6 * can_path / frames, "whole_cycle": 1e6 * (total_cpu - emulator_cpu) / frames},
        "frames_per_cycle": frames,
        "bus_load": {
            "buses": len(loads),
            "max_nominal_pct": round(100 * max(b.nominal for b in loads), 1),
            "max_worst_case_pct": round(100 * max(b.worst_case for b in loads), 1),
            "per_bus_nominal_pct": {b.bus: round(100 * b.nominal, 1) for b in loads},
        },
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robot", default="g1")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of control per rate (the issue asks 60 at 500 Hz)")
    parser.add_argument("--rates", type=float, nargs="+", default=[500.0, 1000.0])
    parser.add_argument("--controller", choices=("pd", "wbc"), default="pd")
    parser.add_argument("--no-log", action="store_true", help="run without the MCAP log")
    parser.add_argument("--rt-priority", type=int, default=None, help="run the loop under SCHED_FIFO at this priority")
    parser.add_argument("--no-pin", action="store_true",
                        help="with --emulator process: do not pin the loop's thread and the emulator to different CPUs")
    parser.add_argument("--emulator", choices=("process", "lockstep"), default="process",
                        help="the emulator in its own process on giwbc-unix channels (as motors on their own hardware), "
                             "or in the loop's thread on python-can virtual buses (lockstep)")
    args = parser.parse_args()

    description = load(args.robot)
    model = description.build_mujoco()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        results = [
            run_rate(description, model, rate, args.seconds, args.controller, Path(tmp), not args.no_log, args.rt_priority, args.emulator,
                     not args.no_pin)
            for rate in args.rates
        ]
    print(json.dumps({
        "benchmark": "deploy_loop",
        "robot": args.robot,
        "joints": description.dofs,
        "controller": args.controller,
        "log": not args.no_log,
        "scheduler": "default (CFS)" if args.rt_priority is None else f"SCHED_FIFO {args.rt_priority}",
        "transport": ("giwbc-unix channels (AF_UNIX SOCK_SEQPACKET), emulator in its own process" if args.emulator == "process"
                      else "python-can virtual, emulator in the loop thread (lockstep)"),
        "machine": {"cpus": os.cpu_count(), "loadavg_before": [round(x, 2) for x in load_before],
                    "loadavg_after": [round(x, 2) for x in os.getloadavg()], "python": sys.version.split()[0]},
        "results": results,
    }))  # fmt: skip


if __name__ == "__main__":
    main()
