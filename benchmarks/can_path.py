"""The host's CAN path of one deploy cycle, without an emulator (one JSON object).

``giwbc deploy``'s :class:`~giwbc.hal.can_robot.CanRobot` (``wait_for_replies=False``, as with the
emulator in its own process) on the G1's hardware plan, each bus a ``giwbc-unix`` channel whose
motor end is an in-process socket pair: before each cycle the motor side writes one reply per motor
(each motor's own reply encoding, fixed random states), after it the commands are read back
(neither is timed). Timed per cycle: ``exchange`` (drain the replies, decode, send the held
command, read the IMU), the safety supervisor's ``check`` and ``set_joint_impedance``.

Unlike ``benchmarks/deploy_loop.py`` no emulator shares the machine, so the figures are the code's
own cost: ``min`` and ``p10`` hardly move with the machine's load, ``p50`` somewhat. Medians over
``--repeat`` runs of ``--cycles`` cycles each.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import giwbc  # noqa: E402,F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
import numpy as np  # noqa: E402

from giwbc.hal.bus import CanBusLink  # noqa: E402
from giwbc.hal.can_robot import CanRobot  # noqa: E402
from giwbc.hal.frames import frames_of  # noqa: E402
from giwbc.hal.hardware import load_hardware  # noqa: E402
from giwbc.hal.safety import SafetyConfig, SafetySupervisor  # noqa: E402
from giwbc.hal.unix_bus import UnixCanBus  # noqa: E402
from giwbc.robot import load  # noqa: E402
from giwbc.robot.interface import ImpedanceCommand, ImuReading  # noqa: E402


class _Imu:
    """An IMU at rest, a new sample per read (2 ms apart)."""

    def __init__(self) -> None:
        self.samples = 0

    def read(self) -> ImuReading:
        self.samples += 1
        return ImuReading(np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.array([0.0, 0.0, 9.81]), 0.002 * self.samples)


def run(robot_name: str, cycles: int, seed: int) -> dict[str, dict[str, float]]:
    description = load(robot_name)
    plan = load_hardware(description.folder / "hardware.toml", 500.0, joint_names=description.joint_names, interface="virtual")
    rng = np.random.default_rng(seed)
    links, motors, replies = [], [], []
    for bus in plan.buses:
        host, motor = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        for end in (host, motor):
            end.setblocking(False)
        link = CanBusLink(UnixCanBus(f"can-path-{bus.name}", _socket=host), bus.make_protocol(), name=bus.name)
        links.append(link)
        motors.append(motor)
        protocol = link.protocol
        replies.append([frames_of([protocol.encode_reply(m.can_id, 0.1 * rng.normal(), 0.1 * rng.normal(), rng.normal())]).tobytes()
                        for m in protocol.motors])  # fmt: skip
    robot = CanRobot(description, plan, imu=_Imu(), links=links, wait_for_replies=False)  # type: ignore[arg-type]
    supervisor = SafetySupervisor(description, SafetyConfig(), bus_names=tuple(b.name for b in plan.buses))
    dofs = description.dofs
    command = ImpedanceCommand(description.default_positions.copy(), np.zeros(dofs), np.full(dofs, 40.0), np.full(dofs, 2.0), np.zeros(dofs))
    robot.set_joint_impedance(command)
    times: dict[str, list[float]] = {"exchange": [], "safety_check": [], "set_joint_impedance": []}
    warm = 200
    try:
        for k in range(cycles + warm):
            for end, frames in zip(motors, replies):
                for frame in frames:
                    end.send(frame)
            a = time.perf_counter()
            report = robot.exchange(0.002 * k)
            b = time.perf_counter()
            q, dq, tau = robot.measured
            faults = supervisor.check(report, q, dq, tau, robot.latest_imu)
            c = time.perf_counter()
            robot.set_joint_impedance(command)
            d = time.perf_counter()
            for end in motors:  # the motors take the commands
                while True:
                    try:
                        end.recv(72)
                    except BlockingIOError:
                        break
            if not report.complete or faults:
                raise RuntimeError(f"cycle {k}: missing replies {int(report.missing.sum())}, faults {faults}")
            if k >= warm:
                times["exchange"].append(b - a)
                times["safety_check"].append(c - b)
                times["set_joint_impedance"].append(d - c)
    finally:
        robot.close()
        for end in motors:
            end.close()
    return {name: {"min": 1e6 * float(np.min(v)), "p10": 1e6 * float(np.percentile(v, 10)), "p50": 1e6 * float(np.median(v))}
            for name, v in times.items()}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robot", default="g1")
    parser.add_argument("--cycles", type=int, default=5000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0, help="the motors' reply states")
    args = parser.parse_args()
    load_before = os.getloadavg()
    runs = [run(args.robot, args.cycles, args.seed) for _ in range(max(1, args.repeat))]
    print(json.dumps({
        "benchmark": "can_path",
        "robot": args.robot,
        "cycles": args.cycles,
        "repeat": len(runs),
        "seed": args.seed,
        "per_cycle_us": {name: {stat: round(float(np.median([r[name][stat] for r in runs])), 1) for stat in ("min", "p10", "p50")}
                         for name in runs[0]},
        "machine": {"cpus": os.cpu_count(), "loadavg_before": [round(x, 2) for x in load_before],
                    "loadavg_after": [round(x, 2) for x in os.getloadavg()], "python": sys.version.split()[0]},
    }))  # fmt: skip


if __name__ == "__main__":
    main()
