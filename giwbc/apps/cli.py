"""The giwbc command line: list robots, simulate, walk, train, evaluate, play and deploy policies.

Run `giwbc COMMAND --help` for a command's options (units and defaults shown). Bad input ends
before any work with one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

import numpy as np

from giwbc.apps.arguments import ROBOT_HELP, HelpFormatter, add_command, seconds
from giwbc.apps.deploy import add_deploy_command
from giwbc.apps.walk_evaluation import add_evaluate_command
from giwbc.apps.motors import add_motors_command
from giwbc.apps.log_report import add_log_command
from giwbc.apps.play import add_play_command
from giwbc.apps.sim_to_sim import add_sim_to_sim_command
from giwbc.apps.training import add_train_command
from giwbc.apps.walk import add_walk_command
from giwbc import __version__
from giwbc.errors import ConfigError, GiwbcError
from giwbc.robot import MujocoRobot, RobotDescriptionError, load
from giwbc.robot.description import robot_search_path, scan_robots
from giwbc.robot.standing import StandingSummary, base_tilt_deg, pd_hold_command
from giwbc.apps.demo import run_demo

GRAVITY = 9.81
SIM_MAX_SECONDS = 600.0  # giwbc sim: 10 simulated minutes (a few minutes of wall time)
DEMO_MAX_SECONDS = 60.0  # giwbc demo: the pushes are at 2, 4.5 and 7 s


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr (``giwbc sim: error: ...``), exit 2.
    Subcommands' parsers are of the same class (argparse passes the class on)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def version() -> str:
    """The installed distribution's version (the package's own when not installed)."""
    try:
        return importlib.metadata.version("giwbc")
    except importlib.metadata.PackageNotFoundError:
        return __version__


def cmd_robots(_: argparse.Namespace) -> int:
    """List the robots found (GIWBC_ROBOT_PATH, then the shipped ones) with DoF and mass."""
    descriptions, broken = scan_robots()
    for robot in broken:  # one broken robot never hides the others
        print(f"giwbc robots: warning: skipped robot {robot.name!r}: {robot.error}", file=sys.stderr)
    if not descriptions:
        searched = ", ".join(str(folder) for folder in robot_search_path()) or "no folder"
        found = f"none of the {len(broken)} found loads (see above)" if broken else "none found"
        raise RobotDescriptionError(f"no robots: {found} in {searched}; "
                                    "set GIWBC_ROBOT_PATH to folders holding one folder per robot, each with a robot.toml")
    print(f"{'robot':<12}{'dofs':>5}{'actuated':>10}{'mass (kg)':>11}  base      description")
    for description in descriptions:
        name = description.folder.name  # the name `--robot` takes
        base = "floating" if description.floating_base else "fixed"
        print(
            f"{name:<12}{description.dofs:>5}{int(description.actuated.sum()):>10}"
            f"{description.total_mass:>11.2f}  {base:<9} {description.description}"
        )
    return 0


def run_pd_hold(robot_name: str, seconds: float) -> StandingSummary:
    """Hold the default pose with joint PD in MuJoCo, headless, and summarise."""
    description = load(robot_name)
    robot = MujocoRobot(description)
    robot.set_joint_impedance(pd_hold_command(description))
    steps_per_check = max(1, int(round(0.02 / description.timestep)))
    start = robot.base_state().position.copy()
    heights, tilts = [start[2]], [0.0]
    wall = time.perf_counter()
    while robot.time() < seconds - 1e-9:
        robot.step(steps_per_check)
        heights.append(robot.base_state().position[2])
        tilts.append(base_tilt_deg(robot))
    wall = time.perf_counter() - wall
    vertical = sum(robot.contact_wrench(c.link).force[2] for c in description.contacts)
    return StandingSummary(
        seconds=robot.time(),
        wall_seconds=wall,
        min_base_height=float(min(heights)),
        max_base_height=float(max(heights)),
        max_tilt_deg=float(max(tilts)),
        base_drift_m=float(np.linalg.norm(robot.base_state().position[:2] - start[:2])),
        vertical_contact_force=float(vertical),
        weight=description.total_mass * GRAVITY,
        floating_base=description.floating_base,
    )


def cmd_sim(args: argparse.Namespace) -> int:
    """Headless joint-PD hold at the default pose, with a short summary."""
    summary = run_pd_hold(args.robot, args.seconds)
    if args.json:
        print(json.dumps({**summary.__dict__, "real_time_factor": summary.real_time_factor, "stood": summary.stood}))
    else:
        print(f"{args.robot}: joint-PD hold for {summary.seconds:.2f} s simulated in {summary.wall_seconds:.2f} s "
              f"(real-time factor {summary.real_time_factor:.1f})")
        if summary.floating_base:
            print(f"  base height {summary.min_base_height:.3f}..{summary.max_base_height:.3f} m, max tilt "
                  f"{summary.max_tilt_deg:.2f} deg, drift {1000 * summary.base_drift_m:.1f} mm")
            print(f"  vertical contact force {summary.vertical_contact_force:.1f} N vs weight {summary.weight:.1f} N")
            print("  stood" if summary.stood else "  FELL")
    return 0 if summary.stood else 1


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job: what giwbc can do today, end to end."""
    video = None if args.no_video else args.video
    if video is not None and Path(video).suffix.lower() not in (".mp4", ".gif"):
        raise ConfigError(f"--video {video}: expected a .mp4 or .gif file")  # before minutes of simulation, not after
    return run_demo(seconds=args.seconds, video=video)


def build_parser() -> argparse.ArgumentParser:
    """The ``giwbc`` parser and every subcommand's (tests walk it to check every numeric option)."""
    parser = Parser(prog="giwbc", description=__doc__, formatter_class=HelpFormatter)
    parser.add_argument("--version", action="version", version=f"giwbc {version()}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_command(commands, "robots", cmd_robots.__doc__ or "").set_defaults(run=cmd_robots)
    sim = add_command(commands, "sim", cmd_sim.__doc__ or "")
    sim.add_argument("--robot", default="g1", help=ROBOT_HELP)
    sim.add_argument("--seconds", type=seconds(SIM_MAX_SECONDS), default=5.0,
                     help=f"simulated seconds, in (0, {SIM_MAX_SECONDS:g}]")
    sim.add_argument("--json", action="store_true", help="print one JSON object")
    sim.set_defaults(run=cmd_sim)
    demo = add_command(commands, "demo", cmd_demo.__doc__ or "")
    demo.add_argument("--seconds", type=seconds(DEMO_MAX_SECONDS), default=10.0,
                      help=f"simulated seconds of each standing push test (pushes at 2, 4.5 and 7 s), in (0, {DEMO_MAX_SECONDS:g}]")
    demo.add_argument("--video", default="runs/demo_push_recovery.mp4",
                      help="side-by-side video of the push recovery, when an offscreen GL backend is available")
    demo.add_argument("--no-video", action="store_true", help="no video even when GL is available")
    demo.set_defaults(run=cmd_demo)
    add_train_command(commands)
    add_play_command(commands)
    add_evaluate_command(commands)
    add_sim_to_sim_command(commands)
    add_deploy_command(commands)
    add_motors_command(commands)
    add_walk_command(commands)
    add_log_command(commands)
    return parser


def one_line(error: BaseException) -> str:
    """An error's message on one line (a multi-line message joined with "; ")."""
    return "; ".join(line.strip() for line in str(error).splitlines() if line.strip()) or type(error).__name__


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command. Foreseen bad input (a :class:`GiwbcError`) is one line on stderr and exit 2;
    Ctrl-C one line and exit 130; anything else is a bug and keeps its traceback."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args))
    except GiwbcError as error:
        print(f"giwbc {args.command}: error: {one_line(error)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C: the user's choice, not a bug (deploy handles its own, with motors off first)
        print(f"giwbc {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
