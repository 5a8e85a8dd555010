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

The emulator runs in the loop's thread (lockstep): its CPU time is in every cycle. Other processes
share this machine's cores; the load average is reported with the results.
"""

from __future__ import annotations

import argparse
import copy
import json
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
from giwbc.hal.hardware import load_hardware  # noqa: E402
from giwbc.hal.runlog import RunLogWriter  # noqa: E402
from giwbc.robot import load  # noqa: E402
from giwbc.runtimes.realtime import RealtimeRuntime, StandingTask, StartupConfig  # noqa: E402


class _CpuMeter:
    """Thread CPU time spent inside the emulator's calls and inside the robot's exchanges."""

    def __init__(self, emulator: ActuatorEmulator, robot: CanRobot) -> None:
        self.total = 0.0  # emulator
        self.exchange = 0.0  # exchanges, emulator included
        for name in ("advance", "answer"):
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


def run_rate(description, model, rate: float, seconds: float, controller: str, log_dir: Path, log: bool, rt_priority: int | None) -> dict:
    plan = load_hardware(description.folder / "hardware.toml", rate, joint_names=description.joint_names, interface="virtual")
    emulator = ActuatorEmulator(plan, description, EmulatorConfig(), model=copy.copy(model))
    estimator = None
    if controller == "wbc":
        from giwbc.robot.estimator import StateEstimator

        estimator = StateEstimator(description)
    robot = CanRobot(description, emulator.host_plan(), imu=emulator.imu_channel, peer=emulator, estimator=estimator)
    meter = _CpuMeter(emulator, robot)
    task = StandingTask(make_controller(controller, description), description.default_positions)
    writer = RunLogWriter(log_dir / f"deploy_loop_{int(rate)}.mcap", description.joint_names, {"benchmark": "deploy_loop"}) if log else None
    runtime = RealtimeRuntime(task, robot, controller_rate=rate, log=writer, rt_priority=rt_priority,
                              startup=StartupConfig(settle_time=0.05, ramp_time=0.5, shutdown_time=0.1, off_delay=0.05))  # fmt: skip
    emulator_cpu_at: dict[str, float] = {}
    exchange_cpu_at: dict[str, float] = {}
    original = runtime._set_phase

    def mark(phase: str) -> None:
        emulator_cpu_at.setdefault(phase, meter.total)
        exchange_cpu_at.setdefault(phase, meter.exchange)
        original(phase)

    runtime._set_phase = mark  # type: ignore[method-assign]
    result = runtime.run(None, seconds)
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
    total_cpu = float(np.mean(stats.cpu)) if stats.cpu else float("nan")
    frames = 2 * len(plan.motors)
    loads = list(plan.loads.values())
    return {
        "rate_hz": rate,
        "seconds": seconds,
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
            "emulator_mean": 1e6 * emulator_cpu,
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
    args = parser.parse_args()

    description = load(args.robot)
    model = description.build_mujoco()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        results = [
            run_rate(description, model, rate, args.seconds, args.controller, Path(tmp), not args.no_log, args.rt_priority)
            for rate in args.rates
        ]
    print(json.dumps({
        "benchmark": "deploy_loop",
        "robot": args.robot,
        "joints": description.dofs,
        "controller": args.controller,
        "log": not args.no_log,
        "scheduler": "default (CFS)" if args.rt_priority is None else f"SCHED_FIFO {args.rt_priority}",
        "transport": "python-can virtual, emulator in the loop thread (lockstep)",
        "machine": {"cpus": os.cpu_count(), "loadavg_before": [round(x, 2) for x in load_before],
                    "loadavg_after": [round(x, 2) for x in os.getloadavg()], "python": sys.version.split()[0]},
        "results": results,
    }))  # fmt: skip


if __name__ == "__main__":
    main()
