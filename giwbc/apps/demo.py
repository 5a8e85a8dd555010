"""``make demo``: G1 in MuJoCo, headless — the whole-body controller against a joint-PD hold
under the same pushes, with the numbers that tell them apart."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from giwbc.robot import MujocoRobot, load
from giwbc.robot.description import RobotDescription
from giwbc.robot.standing import base_tilt_deg, pd_hold_command
from giwbc.apps.evaluation import demo_residual
from giwbc.control import make_balance_controller

GRAVITY = 9.81


@dataclass(frozen=True)
class Push:
    """A force on the pelvis (world frame, N) from ``start`` for ``duration`` seconds."""

    start: float
    duration: float
    force: tuple[float, float, float]


DEFAULT_PUSHES = (
    Push(2.0, 0.2, (0.0, 60.0, 0.0)),  # lateral, the WBC issue's criterion
    Push(4.5, 0.2, (0.0, -60.0, 0.0)),
    Push(7.0, 0.2, (40.0, 0.0, 0.0)),  # sagittal
)


@dataclass(frozen=True)
class PushRunReport:
    controller: str
    stood: bool
    seconds: float
    wall_seconds: float
    max_tilt_deg: float
    com_drift_mm: float
    max_foot_lift_mm: float
    contact_force_over_weight: float
    tick_median_us: float | None = None
    tick_p99_us: float | None = None
    qp_failures: int = 0


def _foot_heights(robot: MujocoRobot, description: RobotDescription) -> np.ndarray:
    return np.array([robot.link_pose(c.link)[0][2] for c in description.contacts])


def run_push_test(controller: str, seconds: float, pushes: tuple[Push, ...] = DEFAULT_PUSHES) -> PushRunReport:
    """Stand G1 for ``seconds`` with ``controller`` ("wbc" at the physics rate, or "pd") under ``pushes``."""
    description = load("g1")
    robot = MujocoRobot(description)
    balance = None
    if controller == "wbc":
        balance = make_balance_controller(description)
    else:
        robot.set_joint_impedance(pd_hold_command(description))
    com_start = robot.data.subtree_com[0].copy()
    feet_start = _foot_heights(robot, description)
    tilt, lift, ticks, failures = 0.0, 0.0, [], 0
    wall = time.perf_counter()
    while robot.time() < seconds - 1e-9:
        now = robot.time()
        force = np.zeros(3)
        for push in pushes:
            if push.start <= now < push.start + push.duration:
                force += push.force
        robot.set_external_wrench(description.base_link, force)
        if balance is not None:
            start = time.perf_counter()
            result = balance.step(robot)
            ticks.append(time.perf_counter() - start)
            failures += int(not result.ok)
        robot.step()
        tilt = max(tilt, base_tilt_deg(robot))
        lift = max(lift, float(np.max(_foot_heights(robot, description) - feet_start)))
        if tilt > 45.0:
            break
    wall = time.perf_counter() - wall
    vertical = sum(robot.contact_wrench(c.link).force[2] for c in description.contacts)
    com_drift = np.linalg.norm(robot.data.subtree_com[0][:2] - com_start[:2])
    return PushRunReport(
        controller=controller,
        stood=tilt < 20.0,
        seconds=robot.time(),
        wall_seconds=wall,
        max_tilt_deg=tilt,
        com_drift_mm=1000 * float(com_drift),
        max_foot_lift_mm=1000 * lift,
        contact_force_over_weight=float(vertical / (description.total_mass * GRAVITY)),
        tick_median_us=float(np.median(ticks) * 1e6) if ticks else None,
        tick_p99_us=float(np.percentile(ticks, 99) * 1e6) if ticks else None,
        qp_failures=failures,
    )


def _print_report(report: PushRunReport) -> None:
    verdict = "stood" if report.stood else "FELL"
    print(f"  {report.controller:<4} {verdict:<6} max tilt {report.max_tilt_deg:5.2f} deg, CoM drift "
          f"{report.com_drift_mm:6.1f} mm, max foot lift {report.max_foot_lift_mm:5.1f} mm, "
          f"contact force / weight {report.contact_force_over_weight:.3f}, "
          f"{report.seconds:.1f} s simulated in {report.wall_seconds:.1f} s")
    if report.tick_median_us is not None:
        print(f"       WBC tick median {report.tick_median_us:.0f} us, p99 {report.tick_p99_us:.0f} us, "
              f"QP failures {report.qp_failures}")


def run_demo(seconds: float = 10.0) -> int:
    """Run G1 under pushes with the WBC and with the joint-PD baseline; print the comparison."""
    print("giwbc demo: Unitree G1 (29 DoF) in MuJoCo at 500 Hz, pushes on the pelvis:")
    for push in DEFAULT_PUSHES:
        print(f"  t = {push.start:.1f} s: {np.linalg.norm(push.force):.0f} N along {np.round(np.array(push.force) / np.linalg.norm(push.force), 2).tolist()} for {push.duration} s")
    wbc = run_push_test("wbc", seconds)
    pd = run_push_test("pd", seconds)
    print("results (QP whole-body controller vs joint-PD hold):")
    _print_report(wbc)
    _print_report(pd)
    demo_residual(episodes=12, force=80.0)  # the shipped residual policy (policies/) over the same WBC
    return 0 if wbc.stood else 1
