"""``make demo``: G1 in MuJoCo, headless — the whole-body controller against a joint-PD hold
under the same pushes, with the numbers that tell them apart; then walking, and a push that the
feet-in-place controller loses but stepping recovers (side by side in a video when an offscreen
OpenGL backend is available — never required)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from giwbc.apps.play import write_video
from giwbc.errors import RenderingUnavailableError
from giwbc.locomotion.simulation import Push as StepPush
from giwbc.locomotion.simulation import WalkRun, simulate_walk
from giwbc.robot import MujocoRobot, load
from giwbc.robot.description import RobotDescription
from giwbc.robot.standing import base_tilt_deg, pd_hold_command
from giwbc.apps.evaluation import demo_residual
from giwbc.control import make_balance_controller
from giwbc.runtimes.rendering import offscreen_backend, offscreen_renderer

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


WALK_COMMAND = (0.4, 0.0, 0.0)  # m/s, m/s, rad/s
WALK_SECONDS = 6.0
STEP_PUSH = StepPush(1.0, 100.0, math.pi)  # 100 N x 0.2 s (20 N·s) straight backward on the pelvis
STEP_PUSH_SECONDS = 3.0
VIDEO_FPS = 15.0  # (software GL renders ~0.1 s a frame: few, small frames keep `make demo` short)


class _Camera:
    """Offscreen frames following the base (:func:`giwbc.runtimes.rendering.offscreen_renderer`)."""

    def __init__(self, size: tuple[int, int] = (240, 320)) -> None:
        self.size = size
        self._renderer: Any = None
        self._camera: Any = None

    def __call__(self, robot: MujocoRobot) -> np.ndarray:
        if self._renderer is None:
            self._renderer = offscreen_renderer(robot.model, *self.size)
            flags = self._renderer.scene.flags  # (no shadows, reflections, skybox: 3x faster in software GL)
            for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION, mujoco.mjtRndFlag.mjRND_SKYBOX):
                flags[flag] = False
            self._camera = mujoco.MjvCamera()
            self._camera.distance, self._camera.azimuth, self._camera.elevation = 3.0, 90.0, -12.0  # from the side
        self._camera.lookat[:] = [0.0, 0.0, 0.6]
        self._renderer.update_scene(robot.data, camera=self._camera)
        return self._renderer.render()


def _walk_line(label: str, run: WalkRun) -> str:
    verdict = f"FELL at {run.fall_time:.2f} s" if run.fell else "no fall"
    return (f"  {label:<14} {verdict:<16} steps {run.steps:2d} (recovery {run.recovery_steps}), "
            f"final tilt {math.degrees(run.final_tilt):5.1f} deg, WBC failures {run.wbc_failures}")


def run_walking_demo(video: str | None = None) -> bool:
    """Walk forward; then the same backward push on the feet-in-place balance controller and on the
    walking controller (stepping). Returns True when stepping recovered a push that feet-in-place
    control lost. ``video``: a side-by-side video of the push (skipped with a note without GL)."""
    description = load("g1")
    walk = simulate_walk(description, WALK_COMMAND, WALK_SECONDS, seed=0)
    print(f"walking at (vx, vy, yaw rate) = {WALK_COMMAND} for {WALK_SECONDS:.0f} s (model-based stepping on the same WBC):")
    print(_walk_line("walk", walk))
    print(f"  speed {np.round(walk.mean_velocity, 3).tolist()} m/s (per-step averages), RMS velocity tracking error "
          f"{walk.tracking_rms:.3f} m/s per step, {walk.per_tick.tracking_rms_per_tick_heading_xy:.3f} m/s per tick (heading frame), "
          f"distance {np.round(walk.distance, 2).tolist()} m")
    cameras: dict[str, Any] = {}
    every = max(1, int(round(1.0 / (VIDEO_FPS * description.timestep))))
    if video:
        try:
            offscreen_backend()
            cameras = {"in_place": _Camera(), "stepping": _Camera()}
        except RenderingUnavailableError as error:
            print(f"  (no video: {error})")
    runs = {
        arm: simulate_walk(description, (0.0, 0.0, 0.0), STEP_PUSH_SECONDS, pushes=(STEP_PUSH,), command_start=None,
                           stepping=arm == "stepping", render=cameras.get(arm), render_every=every if cameras else 0)
        for arm in ("in_place", "stepping")
    }
    print(f"push recovery: {STEP_PUSH.force:.0f} N for {STEP_PUSH.duration} s ({STEP_PUSH.impulse:.0f} N·s) straight backward at "
          f"t = {STEP_PUSH.start:.1f} s, standing:")
    print(_walk_line("feet in place", runs["in_place"]))
    print(_walk_line("stepping", runs["stepping"]))
    if cameras:
        left, right = runs["in_place"].frames, runs["stepping"].frames
        frames = [np.hstack([left[min(i, len(left) - 1)], right[i]]) for i in range(len(right))]
        path = write_video(video, frames, fps=1.0 / (every * description.timestep))  # type: ignore[arg-type]
        print(f"  video (left: feet in place, right: stepping): {path}")
    recovered = runs["in_place"].fell and not runs["stepping"].fell
    print("  stepping recovered the push that feet-in-place control lost" if recovered else "  (no difference this time)")
    return recovered and not walk.fell


def run_demo(seconds: float = 10.0, video: str | None = "runs/demo_push_recovery.mp4") -> int:
    """Run G1 under pushes with the WBC and with the joint-PD baseline; print the comparison."""
    print("giwbc demo: Unitree G1 (29 DoF) in MuJoCo at 500 Hz, pushes on the pelvis:")
    for push in DEFAULT_PUSHES:
        print(f"  t = {push.start:.1f} s: {np.linalg.norm(push.force):.0f} N along {np.round(np.array(push.force) / np.linalg.norm(push.force), 2).tolist()} for {push.duration} s")
    wbc = run_push_test("wbc", seconds)
    pd = run_push_test("pd", seconds)
    print("results (QP whole-body controller vs joint-PD hold):")
    _print_report(wbc)
    _print_report(pd)
    stepped = run_walking_demo(video)
    demo_residual(episodes=12, force=80.0)  # the shipped residual policy (policies/) over the same WBC
    return 0 if wbc.stood and stepped else 1
