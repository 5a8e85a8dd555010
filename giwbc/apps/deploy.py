"""``giwbc deploy``: run a controller (and optionally a policy) on CAN actuators, or rehearse it on
the actuator emulator: the command line (:func:`add_deploy_command`; ``python -m giwbc.apps.deploy``).

The deployment is three modules beside this one: :mod:`giwbc.apps.deploy_options` (what a
deployment is asked and what it reports), :mod:`giwbc.apps.deploy_setup` (which task and
controller ``--task``, ``--controller`` and ``--policy`` choose, and the combinations refused) and
:mod:`giwbc.apps.deploy_run` (the procedure, :func:`deploy`; its docstring describes the run, the
exit codes, the emulator modes, walking, fault rehearsal and the IMU options); the walking
controller on the deployment path is :mod:`giwbc.apps.deploy_walk`, the hardware checks
:mod:`giwbc.apps.deploy_hardware`. Their public names are importable from here too.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from typing import Any

from giwbc.apps.arguments import ROBOT_HELP, HelpFormatter, add_command, integer, number, port, seconds
from giwbc.apps.deploy_dds import DDS_FAULT_CASES
from giwbc.apps.deploy_options import CONTROLLERS, EMULATOR_MODES, FIRST_RUN_CONTROLLER, TASKS, DeployOptions, DeployOutcome
from giwbc.apps.deploy_run import deploy, scene_channels
from giwbc.apps.deploy_setup import (
    WALK_ENV, WbcHold, build_task, check_layout, check_policy_metadata, choose_task, load_policy, make_controller,
)  # fmt: skip
from giwbc.apps.deploy_walk import add_walk_arguments, walk_command, walker_overrides
from giwbc.apps.live import DEFAULT_PORT, require_foxglove
from giwbc.errors import DeployError, GiwbcError
from giwbc.robot.noise import IMU_PROFILES
from giwbc.runtimes.faults import fault_case
from giwbc.runtimes.os_settings import MAX_CPU_LATENCY_US, RT_PRIORITY_RANGE
from giwbc.runtimes.phases import StartupConfig

MAX_SECONDS = 86_400.0  # a day: the longest run (or fault time) the command line takes, s
RATE_RANGE = (50.0, 2000.0)  # Hz: the control rates the command line takes (the plan's buses and a policy's rate check further)
RAMP_RANGE = (0.2, 60.0)  # s: a shorter start-up ramp is a jump to the default pose
MAX_SCENE_RATE = 500.0  # Hz of the logged 3D scene

DESCRIPTION = """Run a controller (and optionally a policy) on CAN actuators, or rehearse it on the
actuator emulator (--emulate). Every option is checked before a bus is opened or a motor enabled.

Start-up: read every joint without torque, enable, settle, ramp to the default pose (--ramp), then,
for controllers that need the base state (wbc, walk, policies), hold still until the state
estimator has calibrated the IMU on both feet (progress printed every second), then run --seconds.

Exit codes: 0 clean run; 2 refused before start (bad option, plan, policy, hardware); 1 stopped by
a fault (damping, then motors off); 128 + the signal for SIGINT, SIGTERM, SIGHUP, SIGQUIT.

First run on a gantry: giwbc deploy --first-run (joint-PD hold, reduced torque and gains).
"""


def add_deploy_command(commands: Any) -> argparse.ArgumentParser:
    """Add ``giwbc deploy`` to an argparse subparsers object. Every number is checked by its type
    (finite, within its physical range) and every option and combination before a bus is opened."""
    parser = add_command(commands, "deploy", "run on CAN actuators, or rehearse on the emulator (--emulate)",
                         description=DESCRIPTION)  # fmt: skip
    parser.add_argument("--robot", default="g1", help=ROBOT_HELP)
    parser.add_argument("--policy", default=None, help="policy .onnx (or its metadata .json); optional")
    parser.add_argument("--task", choices=TASKS, default=None,
                        help="with a policy: its own (walk for a G1Walk-v0 policy, else balance); stand without")
    parser.add_argument("--controller", choices=CONTROLLERS, default=None,
                        help=f"wbc: whole-body QP; pd: joint-PD hold; walk: the walking WBC (default: wbc; "
                             f"{FIRST_RUN_CONTROLLER} with --first-run, the only one a gantry runs)")  # fmt: skip
    add_walk_arguments(parser)
    parser.add_argument("--hardware", default=None, help="hardware plan (default: the robot folder's hardware.toml, hardware_dds.toml with --transport dds)")
    parser.add_argument("--transport", choices=("can", "dds"), default="can",
                        help="can: the plan's CAN buses; dds: Unitree's low-level DDS interface (rt/lowcmd, rt/lowstate: a G1 as Unitree builds it)")
    parser.add_argument("--release-service", action="store_true",
                        help="dds: release the robot's locomotion service through Unitree's motion switcher before any motor is enabled "
                             "(refuses to start if it is not released in time); with --emulate the emulator plays that service")
    parser.add_argument("--restore-service", action="store_true",
                        help="dds, with --release-service: select the released mode again once the motors are off")
    parser.add_argument("--service-timeout", type=seconds(60.0), default=5.0, help="s the release (or the restore) may take")
    parser.add_argument("--emulate", action="store_true", help="rehearse on the actuator emulator instead of the configured buses")
    parser.add_argument("--plant", default=None, metavar="NAME|FILE",
                        help="with --emulate: the emulated robot's plant, a shipped variant of the robot (e.g. lagged_actuators, "
                             "frictional_joints: robots/<robot>/plants), a variant .toml or an MJCF file of the same robot "
                             "(default: the description's own model)")  # fmt: skip
    parser.add_argument("--emulator", choices=EMULATOR_MODES, default="lockstep",
                        help="with --emulate: in the control loop's thread on virtual buses (lockstep), or in its own process (real time)")
    parser.add_argument("--reply-lag", type=integer(0, 1), default=None, metavar="CYCLES",
                        help="with --emulate: 0, the replies to a cycle's commands are read in that cycle (lockstep's default, as "
                             "the host does on CAN hardware); 1, at the next cycle, one more period of sense-to-act latency (the "
                             "process emulator's timing; with lockstep in the emulator's time, deterministic)")  # fmt: skip
    parser.add_argument("--seconds", type=seconds(MAX_SECONDS, allow_zero=True), default=10.0,
                        help=f"s of control after the start-up (ramp, IMU calibration), 0 to {MAX_SECONDS:g}")
    parser.add_argument("--unpaced", action="store_true",
                        help="with --emulator lockstep: as fast as the machine allows, in the emulator's time (no real-time pacing)")
    parser.add_argument("--rate", type=number(*RATE_RANGE, unit="Hz"), default=500.0,
                        help=f"control rate, Hz ({RATE_RANGE[0]:g} to {RATE_RANGE[1]:g}; the plan's buses must carry it)")
    parser.add_argument("--log", default=None, help="run log (.mcap); default runs/deploy-<robot>-<time>.mcap")
    parser.add_argument("--ramp", type=number(*RAMP_RANGE, unit="s"), default=2.0,
                        help=f"start-up ramp from the measured pose to the default pose, s ({RAMP_RANGE[0]:g} to {RAMP_RANGE[1]:g})")
    parser.add_argument("--rt-priority", type=integer(*RT_PRIORITY_RANGE), default=None, metavar="PRIO",
                        help="SCHED_FIFO priority of the control loop, 1 to 99 (needs root or CAP_SYS_NICE: "
                             "refused -> exit 2 before any motor is enabled)")  # fmt: skip
    parser.add_argument("--cpu-latency", type=number(0, MAX_CPU_LATENCY_US, unit="us"), default=None, metavar="US",
                        help="while the motors are on, keep the CPUs' wake-up latency at most US microseconds (0: idle CPUs poll; "
                             "Linux PM QoS, /dev/cpu_dma_latency, needs root; refused -> said, the run goes on): "
                             "cycles do not start on a CPU waking from a halt")  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print one JSON summary at the end (progress goes to stderr)")
    parser.add_argument("--imu", choices=("emulated", "serial", "can"), default=None,
                        help="with --emulate: the IMU device the emulator imitates, read through the real driver (default: the plan's)")
    parser.add_argument("--no-preflight", action="store_true", help="skip the SocketCAN pre-flight check of the interfaces")
    parser.add_argument("--emulated-hardware", default=None,
                        help="with --emulate: the emulated robot's true wiring, when it differs from --hardware (calibration rehearsals)")
    parser.add_argument("--first-run", action="store_true",
                        help="robot on a gantry, feet clear: joint-PD hold (--controller pd), reduced torque and gains, "
                             "tighter fall and limit thresholds")  # fmt: skip
    parser.add_argument("--foxglove", action="store_true",
                        help="stream the robot in 3D to Foxglove over a loopback WebSocket (needs foxglove-sdk)")
    parser.add_argument("--foxglove-port", type=port(), default=DEFAULT_PORT, help="with --foxglove: the WebSocket's loopback TCP port")
    parser.add_argument("--scene-rate", type=number(0, MAX_SCENE_RATE, unit="Hz"), default=DeployOptions.scene_rate,
                        help=f"Hz of the 3D scene (transforms, joint states, contact forces) in the log, 0 to {MAX_SCENE_RATE:g}; 0: none")
    parser.add_argument("--fault", default=None, metavar="KIND",
                        help="with --emulate: inject one fault of the fault table (giwbc.runtimes.faults.FAULT_CASES), e.g. bus_off")
    parser.add_argument("--fault-at", type=seconds(MAX_SECONDS, allow_zero=True), default=1.0,
                        help="with --fault: s after the start-up ramp at which the fault starts")
    parser.add_argument("--imu-profile", choices=sorted(IMU_PROFILES), default=None,
                        help="the IMU's class: with --emulate the emulated IMU's errors (mems, cheap: no orientation output); "
                             "sets up the state estimator for it")  # fmt: skip
    parser.set_defaults(run=run_deploy_command)
    return parser


def run_deploy_command(args: argparse.Namespace) -> int:
    """``giwbc deploy``: progress on stdout (stderr with ``--json``), an error once on stderr (one
    line: ``giwbc deploy: error: ...`` with exit 2 before anything started, ``giwbc deploy: stopped
    by a fault: ...`` with exit 1 or 128 + a signal after)."""
    try:
        options = deploy_options(args)
    except GiwbcError as error:
        print(f"giwbc deploy: error: {error}", file=sys.stderr)
        return 2
    try:
        outcome = deploy(options, out=(lambda m: print(m, file=sys.stderr, flush=True)) if args.json else (lambda m: print(m, flush=True)))
    except KeyboardInterrupt:  # Ctrl-C while setting up (the run itself turns it into damping, motors off, exit 130)
        print("giwbc deploy: interrupted before the motors started", file=sys.stderr)
        return 130
    if args.json:
        result = outcome.result
        print(json.dumps({
            "exit_code": outcome.exit_code, "message": outcome.message, "log": outcome.log_path,
            "fault": None if result is None or result.fault is None else result.fault.as_dict(),
            "faults": [] if result is None else [f.kind.value for f in result.faults],
            "timing": None if result is None else result.timing, "standing": outcome.standing, "walking": outcome.walking,
            "calibration": None if outcome.calibration is None else outcome.calibration.as_dict(),
        }))  # fmt: skip
    if outcome.exit_code:
        prefix = "giwbc deploy: error: " if outcome.exit_code == 2 else "giwbc deploy: "
        print(prefix + outcome.message, file=sys.stderr)
    if outcome.result is not None and outcome.result.loop_abandoned:
        # The loop's thread is stuck in a driver (the watchdog stopped the motors): leave without
        # waiting for it at interpreter shutdown.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(outcome.exit_code)
    return outcome.exit_code


def deploy_options(args: argparse.Namespace) -> DeployOptions:
    """The :class:`DeployOptions` of parsed ``giwbc deploy`` arguments; a :class:`~giwbc.errors.GiwbcError`
    naming the option for what argparse cannot check alone (a fault's name, the walking options, ``--walker``'s
    JSON, foxglove-sdk installed), before anything starts."""
    startup = StartupConfig(ramp_time=args.ramp)
    faults: tuple[Any, ...] = ()
    if getattr(args, "fault", None):
        if not args.emulate:
            raise DeployError("--fault injects a fault into the emulator: it needs --emulate")
        dds_case = DDS_FAULT_CASES.get(args.fault)
        if dds_case is not None and getattr(args, "transport", "can") != "dds":
            raise DeployError(f"--fault {args.fault} is a DDS fault: it needs --transport dds")
        try:
            case = dds_case or fault_case(args.fault)
        except ValueError as error:
            raise DeployError(f"{error}; with --transport dds also: {', '.join(DDS_FAULT_CASES)}") from None
        faults = case.injections(startup.settle_time + startup.ramp_time + args.fault_at)
    if args.foxglove:
        require_foxglove()  # before the motors, not after
    walk = walk_command(args)
    walker = walker_overrides(args)
    return DeployOptions(
        robot=args.robot, policy=args.policy, task=args.task, controller=args.controller, hardware=args.hardware,
        emulate=args.emulate, emulator_mode=args.emulator, seconds=args.seconds, control_rate=args.rate, log=args.log, realtime=not args.unpaced,
        startup=startup, rt_priority=args.rt_priority, cpu_latency=args.cpu_latency, faults=faults, imu=args.imu, preflight=not args.no_preflight,
        first_run=args.first_run, emulated_hardware=args.emulated_hardware, scene_rate=args.scene_rate,
        foxglove_port=args.foxglove_port if args.foxglove else None, imu_profile=args.imu_profile, walk=walk, walker=walker,
        transport=getattr(args, "transport", "can"), release_service=getattr(args, "release_service", False),
        restore_service=getattr(args, "restore_service", False), service_timeout=getattr(args, "service_timeout", 5.0),
        plant=getattr(args, "plant", None), reply_lag=getattr(args, "reply_lag", None),
    )  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m giwbc.apps.deploy ...`` (the same as ``giwbc deploy ...``)."""
    parser = argparse.ArgumentParser(prog="giwbc", formatter_class=HelpFormatter)
    add_deploy_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["deploy", *(sys.argv[1:] if argv is None else argv)])
    return int(args.run(args))


__all__ = [
    "CONTROLLERS", "EMULATOR_MODES", "TASKS", "WALK_ENV", "DeployError", "DeployOptions", "DeployOutcome", "WbcHold", "add_deploy_command",
    "build_task", "check_layout", "check_policy_metadata", "choose_task", "deploy", "deploy_options", "load_policy", "main", "make_controller",
    "run_deploy_command", "scene_channels",
]  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
