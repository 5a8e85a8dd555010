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

from giwbc.apps.deploy_options import EMULATOR_MODES, DeployOptions, DeployOutcome
from giwbc.apps.deploy_run import deploy, scene_channels
from giwbc.apps.deploy_setup import (
    CONTROLLERS, TASKS, WALK_ENV, WbcHold, build_task, check_layout, check_policy_metadata, choose_task, load_policy, make_controller,
)  # fmt: skip
from giwbc.apps.deploy_walk import add_walk_arguments, walk_command, walker_overrides
from giwbc.apps.live import DEFAULT_PORT, require_foxglove
from giwbc.errors import DeployError
from giwbc.robot.noise import IMU_PROFILES
from giwbc.runtimes.faults import fault_case
from giwbc.runtimes.os_settings import check_cpu_latency
from giwbc.runtimes.phases import StartupConfig


def add_deploy_command(commands: Any) -> argparse.ArgumentParser:
    """Add ``giwbc deploy`` to an argparse subparsers object."""
    parser = commands.add_parser("deploy", help="run on CAN actuators, or rehearse on the emulator (--emulate)")
    parser.add_argument("--robot", default="g1")
    parser.add_argument("--policy", default=None, help="policy .onnx (or its metadata .json); optional")
    parser.add_argument("--task", choices=TASKS, default=None,
                        help="default: with a policy its own (walk for a G1Walk-v0 policy, else balance), stand without")
    parser.add_argument("--controller", choices=CONTROLLERS, default="wbc", help="whole-body QP, joint-PD hold, or the walking WBC")
    add_walk_arguments(parser)
    parser.add_argument("--hardware", default=None, help="hardware.toml (default: the robot folder's)")
    parser.add_argument("--emulate", action="store_true", help="rehearse on the actuator emulator instead of the configured buses")
    parser.add_argument("--emulator", choices=EMULATOR_MODES, default="lockstep",
                        help="with --emulate: in the control loop's thread on virtual buses (lockstep), or in its own process (real time)")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of control after the start-up ramp")
    parser.add_argument("--unpaced", action="store_true",
                        help="with --emulator lockstep: as fast as the machine allows, in the emulator's time (no real-time pacing)")
    parser.add_argument("--rate", type=float, default=500.0, help="control rate, Hz")
    parser.add_argument("--log", default=None, help="run log (.mcap); default runs/deploy-<robot>-<time>.mcap")
    parser.add_argument("--ramp", type=float, default=2.0, help="start-up ramp to the default pose, s")
    parser.add_argument("--rt-priority", type=int, default=None, help="SCHED_FIFO priority of the control loop (needs CAP_SYS_NICE)")
    parser.add_argument("--cpu-latency", type=float, default=None, metavar="US",
                        help="while the motors are on, keep the CPUs' wake-up latency at most US microseconds (0: idle CPUs poll; "
                             "Linux PM QoS, /dev/cpu_dma_latency, needs root): cycles do not start on a CPU waking from a halt")
    parser.add_argument("--json", action="store_true", help="print one JSON summary at the end")
    parser.add_argument("--imu", choices=("emulated", "serial", "can"), default=None,
                        help="with --emulate: the IMU device the emulator imitates, read through the real driver (default: the plan's)")
    parser.add_argument("--no-preflight", action="store_true", help="skip the SocketCAN pre-flight check of the interfaces")
    parser.add_argument("--emulated-hardware", default=None,
                        help="with --emulate: the emulated robot's true wiring, when it differs from --hardware (calibration rehearsals)")
    parser.add_argument("--first-run", action="store_true",
                        help="robot on a gantry: reduced torque and gains, tighter fall and limit thresholds")
    parser.add_argument("--foxglove", action="store_true",
                        help="stream the robot in 3D to Foxglove over a loopback WebSocket (needs foxglove-sdk)")
    parser.add_argument("--foxglove-port", type=int, default=DEFAULT_PORT, help="the WebSocket's port")
    parser.add_argument("--scene-rate", type=float, default=DeployOptions.scene_rate,
                        help="Hz of the 3D scene (transforms, joint states, contact forces) in the log; 0: none")
    parser.add_argument("--fault", default=None, metavar="KIND",
                        help="with --emulate: inject one fault of the fault table (giwbc.runtimes.faults.FAULT_CASES), e.g. bus_off")
    parser.add_argument("--fault-at", type=float, default=1.0, help="seconds after the start-up ramp at which --fault starts")
    parser.add_argument("--imu-profile", choices=sorted(IMU_PROFILES), default=None,
                        help="the IMU's class: with --emulate the emulated IMU's errors (mems, cheap: no orientation output); "
                             "sets up the state estimator for it")  # fmt: skip
    parser.set_defaults(run=run_deploy_command)
    return parser


def run_deploy_command(args: argparse.Namespace) -> int:
    startup = StartupConfig(ramp_time=args.ramp)
    faults: tuple[Any, ...] = ()
    if getattr(args, "fault", None):
        try:
            case = fault_case(args.fault)
        except ValueError as error:
            print(f"giwbc deploy: error: {error}", file=sys.stderr)
            return 2
        faults = case.injections(startup.settle_time + startup.ramp_time + args.fault_at)
    try:
        check_cpu_latency(args.cpu_latency)
    except ValueError as error:
        print(f"giwbc deploy: error: --cpu-latency: {error}", file=sys.stderr)
        return 2
    if args.foxglove:
        require_foxglove()  # before the motors, not after
    try:
        walk = walk_command(args)
        walker = walker_overrides(args)
    except DeployError as error:
        print(f"giwbc deploy: error: {error}", file=sys.stderr)
        return 2
    options = DeployOptions(
        robot=args.robot, policy=args.policy, task=args.task, controller=args.controller, hardware=args.hardware,
        emulate=args.emulate, emulator_mode=args.emulator, seconds=args.seconds, control_rate=args.rate, log=args.log, realtime=not args.unpaced,
        startup=startup, rt_priority=args.rt_priority, cpu_latency=args.cpu_latency, faults=faults, imu=args.imu, preflight=not args.no_preflight,
        first_run=args.first_run, emulated_hardware=args.emulated_hardware, scene_rate=args.scene_rate,
        foxglove_port=args.foxglove_port if args.foxglove else None, imu_profile=args.imu_profile, walk=walk, walker=walker,
    )  # fmt: skip
    outcome = deploy(options, out=(lambda m: print(m, file=sys.stderr)) if args.json else print)
    if args.json:
        result = outcome.result
        print(json.dumps({
            "exit_code": outcome.exit_code, "message": outcome.message, "log": outcome.log_path,
            "fault": None if result is None or result.fault is None else result.fault.as_dict(),
            "faults": [] if result is None else [f.kind.value for f in result.faults],
            "timing": None if result is None else result.timing, "standing": outcome.standing, "walking": outcome.walking,
            "calibration": None if outcome.calibration is None else outcome.calibration.as_dict(),
        }))  # fmt: skip
    elif outcome.exit_code:
        print(f"giwbc deploy: {outcome.message}", file=sys.stderr)
    if outcome.result is not None and outcome.result.loop_abandoned:
        # The loop's thread is stuck in a driver (the watchdog stopped the motors): leave without
        # waiting for it at interpreter shutdown.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(outcome.exit_code)
    return outcome.exit_code


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m giwbc.apps.deploy ...`` (the same as ``giwbc deploy ...``)."""
    parser = argparse.ArgumentParser(prog="giwbc")
    add_deploy_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["deploy", *(sys.argv[1:] if argv is None else argv)])
    return int(args.run(args))


__all__ = [
    "CONTROLLERS", "EMULATOR_MODES", "TASKS", "WALK_ENV", "DeployError", "DeployOptions", "DeployOutcome", "WbcHold", "add_deploy_command",
    "build_task", "check_layout", "check_policy_metadata", "choose_task", "deploy", "load_policy", "main", "make_controller",
    "run_deploy_command", "scene_channels",
]  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
