"""``giwbc motors check|scan|monitor|zero|calibrate``: bring a CAN robot up, safely by default.

- ``check``: the SocketCAN pre-flight of every planned interface (exists, up, bitrate,
  restart-ms, transmit queue), with the ``ip link`` commands that fix what is wrong. ``check
  --dry-run`` reads and touches no interface: it checks the plan itself against the robot (a
  motor for every joint, torque ranges, bus capacity at ``--rate``) and prints the ``ip link``
  commands that set every planned interface up as the plan wants: the bring-up script for the
  robot's computer, written before the adapters are plugged in.
- ``scan``: which ids answer on which bus, against the plan: missing, extra, wrong bus, and one
  last line: ``matches the plan`` or ``differs from the plan: ...``.
- ``monitor``: joint positions (rad, deg), velocities, torques, temperatures, live, in plan
  order with the plan's sign and zero offset applied; joints outside their limits flagged.
- ``zero JOINT``: make that joint's motor read 0 where it stands and record the joint angle
  there (``--at``, default 0) as its ``zero_offset`` in the plan (backup kept).
- ``calibrate``: the guided procedure of ``giwbc.hal.bringup``: robot in the model's default
  posture (or zero posture), each joint moved by hand in its positive direction; sign and
  zero_offset written to the plan (backup kept); joints that read outside their limits after it
  are named and the command fails.

No command enables a motor: state is read with zero-gain, zero-torque commands. ``zero`` and
``calibrate`` ask before writing (``--yes`` answers for you). ``--dry-run``: against the actuator
emulator of the plan instead of the buses (``--dry-run-plan``: the emulated robot's true wiring,
when it should differ from the plan: a rehearsal of finding a wrong sign or offset). In a dry run
the "move by hand" is done for you (+``--move`` rad on the emulated joint).

Every number is checked by its argparse type (finite, in its range, unit in the help) and errors
are one line on stderr: ``giwbc motors ACTION: error: ...``, exit 2.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from giwbc.apps.arguments import ROBOT_HELP, HelpFormatter, add_command, integer, number
from giwbc.errors import GiwbcError, HardwareConfigError

EXIT_OK, EXIT_PROBLEM, EXIT_CONFIG, EXIT_INTERRUPTED = 0, 1, 2, 130


class Session:
    """The plan, the description and the link (real buses, or the emulator in a dry run)."""

    def __init__(self, args: argparse.Namespace, out: Callable[[str], None]) -> None:
        from giwbc.hal.bringup import BringupLink
        from giwbc.hal.hardware import load_hardware, parse_hardware
        from giwbc.robot.description import load

        self.out = out
        self.description = d = load(args.robot)
        self.path = Path(args.hardware) if args.hardware else d.folder / "hardware.toml"
        self.plan = load_hardware(self.path, args.rate)
        self.emulator: Any = None
        if args.dry_run:
            from giwbc.emulation import ActuatorEmulator

            truth_path = Path(args.dry_run_plan) if args.dry_run_plan else self.path
            truth = parse_hardware(truth_path.read_text(), args.rate, source=str(truth_path), joint_names=d.joint_names, interface="virtual")
            self.emulator = ActuatorEmulator(truth, d)
            chan = {b.name: (b.interface, b.channel) for b in self.emulator.host_plan().buses}
            host = replace(self.plan, buses=tuple(replace(b, interface=chan[b.name][0], channel=chan[b.name][1]) for b in self.plan.buses))
            out(f"dry run: the emulated robot of {truth_path} on virtual buses")
        else:
            host = self.plan
        self.link = BringupLink(host, peer=self.emulator, timeout=args.timeout)
        lo, hi = d.position_limits
        from giwbc.hal.bringup import description_limits

        self.limits = description_limits(d.joint_names, lo, hi)

    def move_by_hand(self, joint: str, delta: float) -> None:
        """Dry run only: the emulated joint moves by ``delta`` rad, as an operator's hand would."""
        robot = self.emulator.robot
        q = robot.data.qpos.copy()
        q[7 + self.description.joint_names.index(joint)] += delta
        robot.reset(q)

    def close(self) -> None:
        self.link.close()
        if self.emulator is not None:
            self.emulator.close()


def _confirm(args: argparse.Namespace, question: str, ask: Callable[[str], str]) -> bool:
    if args.yes:
        return True
    return ask(f"{question} [type yes] ").strip().lower() in ("yes", "y")


# ----------------------------------------------------------------------------- commands
def _robot_plan(args: argparse.Namespace) -> tuple[Any, Path, Any]:
    """The robot, its plan's path and the plan checked against it (joints, torque ranges, bus capacity)."""
    from giwbc.hal.hardware import load_hardware
    from giwbc.robot.description import load

    d = load(args.robot)
    path = Path(args.hardware) if args.hardware else d.folder / "hardware.toml"
    plan = load_hardware(path, args.rate, joint_names=d.joint_names, effort_limits=dict(zip(d.joint_names, d.effort_limits)))
    return d, path, plan


def cmd_check(args: argparse.Namespace, out: Callable[[str], None], ask: Callable[[str], str]) -> int:
    from giwbc.hal.preflight import preflight

    _, path, plan = _robot_plan(args)
    if args.dry_run:
        return _check_plan(plan, path, args, out)
    report = preflight(plan)
    out(str(report))
    return EXIT_OK if report.ok else EXIT_PROBLEM


def _check_plan(plan: Any, path: Path, args: argparse.Namespace, out: Callable[[str], None]) -> int:
    """``check --dry-run``: the plan is valid (it loaded); its loads and the commands that bring
    every planned SocketCAN interface up as the plan wants (no interface read or touched)."""
    from giwbc.hal.preflight import DEFAULT_RESTART_MS, MIN_TXQUEUELEN, cycle_burst

    out(f"dry run: {path} is a valid plan for {len(plan.joints)} joints on {len(plan.buses)} buses at {args.rate:g} Hz (no interface read)")
    for load in plan.loads.values():
        out(f"  {load}")
    buses = [b for b in plan.buses if b.interface == "socketcan"]
    if not buses:
        out("no socketcan bus in the plan: nothing to set up")
        return EXIT_OK
    out("commands that set the planned interfaces up as the plan wants:")
    for b in buses:
        name, queue = str(b.channel), max(2 * cycle_burst(plan, b), MIN_TXQUEUELEN)
        for command in ("down", f"type can bitrate {b.bitrate} restart-ms {DEFAULT_RESTART_MS}", f"txqueuelen {queue}", "up"):
            out(f"    sudo ip link set {name} {command}")
    return EXIT_OK


def cmd_scan(s: Session, args: argparse.Namespace, out: Callable[[str], None], ask: Callable[[str], str]) -> int:
    from giwbc.hal.bringup import scan

    lo, hi = args.ids
    report = scan(s.link, range(lo, hi + 1))
    out(str(report))
    out(scan_verdict(report, len(s.plan.joints)))
    return EXIT_OK if report.ok else EXIT_PROBLEM


def scan_verdict(report: Any, planned: int) -> str:
    """The scan's last line: ``matches the plan`` or ``differs from the plan: ...`` (counts)."""
    if report.ok:
        return f"matches the plan: all {planned} planned motors answered, nothing else did"
    parts = [f"{n} {what}" for n, what in ((len(report.missing), "missing"), (len(report.extra), "extra"),
                                             (len(report.wrong_bus), "apparently on the wrong bus")) if n]  # fmt: skip
    return f"differs from the plan: {', '.join(parts)} (of {planned} planned motors)"


def cmd_monitor(s: Session, args: argparse.Namespace, out: Callable[[str], None], ask: Callable[[str], str]) -> int:
    from giwbc.hal.bringup import limit_violations, read_joints

    live = sys.stdout.isatty() and args.count == 0
    n = 0
    r = read_joints(s.link)
    try:
        while True:
            text = r.table(s.limits)
            out(("\x1b[H\x1b[2J" if live else "") + text)
            n += 1
            if args.count and n >= args.count:
                break
            time.sleep(1.0 / args.hz)
            r = read_joints(s.link)
    except KeyboardInterrupt:
        pass
    problems = limit_violations(r.joints, r.position, s.limits)
    for p in problems:
        out(p)
    return EXIT_OK if r.replied.all() and not problems else EXIT_PROBLEM


def cmd_zero(s: Session, args: argparse.Namespace, out: Callable[[str], None], ask: Callable[[str], str]) -> int:
    from giwbc.hal.bringup import set_zero
    from giwbc.hal.plan_edit import update_plan

    bus, motor = s.plan.motor(args.joint)
    if not _confirm(args, f"set the zero of motor id {motor.can_id} on {bus.name} ({args.joint}) here, joint angle "
                          f"{args.at:g} rad, and write zero_offset = {args.at:g} into {s.path}?", ask):  # fmt: skip
        out("nothing done")
        return EXIT_PROBLEM
    rec = set_zero(s.link, args.joint, args.at)
    out(f"{args.joint}: motor read {rec.motor_before:.4f} rad, now {rec.motor_after:.4f} rad")
    if args.dry_run and not args.write:
        out(f"dry run: {s.path} not written (--write to write it)")
        return EXIT_OK
    backup = update_plan(s.path, {args.joint: {"zero_offset": rec.joint_angle}}, f"giwbc motors zero: motor {rec.bus} id {rec.motor_id}")
    out(f"wrote zero_offset = {rec.joint_angle:g} for {args.joint} into {s.path} (backup {backup.name})")
    return EXIT_OK


def cmd_calibrate(s: Session, args: argparse.Namespace, out: Callable[[str], None], ask: Callable[[str], str]) -> int:
    from giwbc.hal.bringup import CalibrationSession, limit_violations, read_joints
    from giwbc.hal.plan_edit import update_plan

    d = s.description
    joints = list(args.joints) if args.joints else list(s.plan.joints)
    unknown = [j for j in joints if j not in d.joint_names or j not in s.plan.joints]
    if unknown:
        raise HardwareConfigError(f"unknown joint(s) {unknown}")
    posture = d.default_positions if args.posture == "default" else [0.0] * d.dofs
    q_known = {j: float(posture[d.joint_names.index(j)]) for j in joints}
    out(f"1. put the robot in its {args.posture} posture (joint angles from the model), motors unpowered or off")
    if not _confirm(args, "is the robot in that posture?", ask):
        out("nothing done")
        return EXIT_PROBLEM
    session = CalibrationSession(s.link, q_known, s.limits, min_move=args.min_move)
    silent = session.record_known_posture()
    if silent:
        out(f"no answer from {silent}: run `giwbc motors scan`")
        return EXIT_PROBLEM
    failed = []
    for k, j in enumerate(joints):
        out(f"2.{k + 1} move {j} by hand in its positive direction (at least {args.min_move:g} rad), hold it there")
        if s.emulator is not None:
            s.move_by_hand(j, args.move)
            out(f"    dry run: moved the emulated {j} by {args.move:+g} rad")
        elif not _confirm(args, "    moved?", ask):
            failed.append(j)
            continue
        cal = session.record_move(j)
        if cal.ok:
            out(f"    {j}: sign {cal.sign:+d}, zero_offset {cal.zero_offset:.4f} rad (moved {cal.moved:.3f} rad)")
        else:
            failed.append(j)
            out(f"    {j}: NOT calibrated: {'; '.join(cal.problems)}")
        if s.emulator is not None:
            s.move_by_hand(j, -args.move)
    results = session.results()
    if not results:
        out("nothing to write")
        return EXIT_PROBLEM
    changed = {j: v for j, v in results.items() if (s.plan.motor(j)[1].sign, s.plan.motor(j)[1].zero_offset) != (v["sign"], v["zero_offset"])}
    out(f"{len(results)} joint(s) calibrated, {len(changed)} differ from the plan")
    if changed and args.dry_run and not args.write:
        out(f"dry run: {s.path} not written (--write to write it)")
    elif changed and _confirm(args, f"write sign and zero_offset of {len(results)} joint(s) into {s.path} (a backup is kept)?", ask):
        backup = update_plan(s.path, results, "giwbc motors calibrate")
        out(f"wrote {s.path} (backup {backup.name})")
        from giwbc.hal.bringup import BringupLink
        from giwbc.hal.hardware import load_hardware

        new = load_hardware(s.path, args.rate)
        chan = {b.name: (b.interface, b.channel) for b in s.link.plan.buses}
        new = replace(new, buses=tuple(replace(b, interface=chan[b.name][0], channel=chan[b.name][1]) for b in new.buses))
        s.link.close()
        s.link = BringupLink(new, peer=s.emulator, timeout=args.timeout)
    after = read_joints(s.link)
    problems = limit_violations(after.joints, after.position, s.limits)
    for p in problems:
        out(p)
    if problems:
        out("these joints must not be enabled: deploy refuses to start while a joint reads outside its limits")
    return EXIT_OK if not failed and not problems else EXIT_PROBLEM


COMMANDS = {"scan": cmd_scan, "monitor": cmd_monitor, "zero": cmd_zero, "calibrate": cmd_calibrate}


def _stderr(message: str) -> None:
    print(message, file=sys.stderr)


def run_motors_command(
    args: argparse.Namespace, out: Callable[[str], None] = print, ask: Callable[[str], str] = input, err: Callable[[str], None] = _stderr
) -> int:
    """Run ``giwbc motors ACTION``: its report through ``out``; an error once, one line, through ``err`` (exit 2)."""
    try:
        if args.action == "check":
            return cmd_check(args, out, ask)
        session = Session(args, out)
        try:
            return COMMANDS[args.action](session, args, out, ask)
        finally:
            session.close()
    except (GiwbcError, KeyError, OSError, UnicodeDecodeError) as error:
        text = str(error.args[0]) if isinstance(error, KeyError) and error.args else str(error)
        if isinstance(error, UnicodeDecodeError):
            text = f"{getattr(args, 'dry_run_plan', None) or args.hardware or 'the plan'}: not a text (TOML) file"
        err(f"giwbc motors {args.action}: error: {' '.join(text.split())}")
        return EXIT_CONFIG
    except KeyboardInterrupt:  # Ctrl-C before or between the steps (monitor's own loop ends on it cleanly): nothing half-written
        err(f"giwbc motors {args.action}: interrupted")
        return EXIT_INTERRUPTED


def _ids(text: str) -> tuple[int, int]:
    """An argparse type: ``LO-HI`` (or one id), CAN ids within 0..2047."""
    lo, _, hi = text.partition("-")
    try:
        a, b = int(lo), int(hi or lo)
    except ValueError:
        raise argparse.ArgumentTypeError(f"ids must be LO-HI (or one id), integers within 0..2047, got {text!r}") from None
    if not 0 <= a <= b <= 0x7FF:
        raise argparse.ArgumentTypeError(f"ids must be a range within 0..2047, got {text!r}")
    return a, b


MAX_RATE = 2000.0  # Hz: the control rates a plan is checked at (as giwbc deploy --rate)


def add_motors_command(commands: Any) -> argparse.ArgumentParser:
    """Add ``giwbc motors`` and its actions to an argparse subparsers object."""
    parser = add_command(commands, "motors", "bring-up: check interfaces, scan, monitor, zero, calibrate (no torque)", description=(__doc__ or "").replace("``", ""))
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")

    def plan_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--robot", default="g1", help=ROBOT_HELP)
        p.add_argument("--hardware", default=None, help="hardware.toml (default: the robot folder's)")
        p.add_argument("--rate", type=number(50.0, MAX_RATE, unit="Hz"), default=500.0,
                       help=f"control rate the plan's bus loads are checked at, Hz (50 to {MAX_RATE:g})")

    def common(p: argparse.ArgumentParser) -> None:
        plan_options(p)
        p.add_argument("--dry-run", action="store_true", help="against the actuator emulator of the plan, not the buses")
        p.add_argument("--dry-run-plan", default=None, help="with --dry-run: the emulated robot's true wiring (default: the plan)")
        p.add_argument("--timeout", type=number(0.0, 5.0, unit="s", low_open=True), default=0.02,
                       help="reply timeout per request on the buses, s (0 to 5)")
        p.add_argument("--yes", action="store_true", help="answer yes to every confirmation")

    check = add_command(sub, "check", "SocketCAN pre-flight of the plan's interfaces (--dry-run: the plan only, no interface)")
    plan_options(check)
    check.add_argument("--dry-run", action="store_true",
                       help="read and touch no interface: check the plan against the robot and print the ip link commands "
                            "that set its interfaces up")  # fmt: skip
    common(scan := add_command(sub, "scan", "which ids answer on which bus, against the plan"))
    scan.add_argument("--ids", type=_ids, default=(1, 32), metavar="LO-HI", help="CAN id range to probe, e.g. 1-32 (within 0-2047)")
    common(monitor := add_command(sub, "monitor", "joint states live, no torque"))
    monitor.add_argument("--hz", type=number(0.0, 50.0, unit="Hz", low_open=True), default=5.0, help="refreshes per second, Hz (0 to 50)")
    monitor.add_argument("--count", type=integer(0, 1_000_000), default=0, help="refreshes before exiting (0: until Ctrl-C)")
    common(zero := add_command(sub, "zero", "set a motor's zero where its joint stands"))
    zero.add_argument("joint", help="the joint's name (as in the plan)")
    zero.add_argument("--at", type=number(-math.tau, math.tau, unit="rad"), default=0.0,
                      help="the joint angle where it stands, rad (|at| <= 2 pi): its new zero_offset")
    zero.add_argument("--write", action="store_true", help="with --dry-run: write the plan anyway")
    common(cal := add_command(sub, "calibrate", "sign and zero_offset of each joint, written to the plan"))
    cal.add_argument("--joints", nargs="*", default=None, help="default: every joint of the plan")
    cal.add_argument("--posture", choices=("default", "zero"), default="default", help="the known posture the robot is put in")
    cal.add_argument("--min-move", type=number(0.0, math.pi, unit="rad", low_open=True), default=0.1,
                     help="least hand move that counts, rad (0 to pi)")
    cal.add_argument("--move", type=number(0.0, math.pi, unit="rad", low_open=True), default=0.2,
                     help="with --dry-run: the emulated hand move, rad (0 to pi)")
    cal.add_argument("--write", action="store_true", help="with --dry-run: write the plan anyway")
    parser.set_defaults(run=lambda args: run_motors_command(args))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="giwbc", formatter_class=HelpFormatter)
    add_motors_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["motors", *(sys.argv[1:] if argv is None else argv)])
    return int(args.run(args))


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["add_motors_command", "run_motors_command", "scan_verdict"]
