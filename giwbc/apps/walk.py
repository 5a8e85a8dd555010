"""``giwbc walk``: the walking controller in MuJoCo from a velocity command, with an optional push
and video, and a short summary (speed, velocity tracking, steps, falls, WBC failures)."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import Any

import mujoco
import numpy as np

from giwbc.plants import PlantSpec, resolve_plant
from giwbc.apps.arguments import ROBOT_HELP, add_command, number, port, seconds, seed
from giwbc.apps.live import DEFAULT_PORT, HOST, ScenePublisher, require_foxglove
from giwbc.apps.progress import Progress, add_progress_argument, wants_progress
from giwbc.errors import ConfigError
from giwbc.locomotion.footsteps import FootstepPlanner, VelocityCommand
from giwbc.locomotion.push_scoring import SETTLE_AFTER_PUSH_S
from giwbc.locomotion.simulation import Push, WalkRun, simulate_walk
from giwbc.locomotion.walker_config import WalkerConfig
from giwbc.robot import RobotDescription, load
from giwbc.apps.play import write_video
from giwbc.runtimes.rendering import offscreen_renderer

VIDEO_FPS = 30.0
PROGRESS_S = 0.1  # simulated seconds between progress updates without a video
LIVE_HZ = 30.0  # the Foxglove stream's rate
MAX_SECONDS = 600.0  # simulated; the walker runs at about real time on one core
MAX_SPEED = 5.0  # m/s and rad/s accepted on the command line (then clamped to the gait's limits, and said so)
MAX_PUSH = 1000.0  # N: 200 N·s over the 0.2 s push, far beyond what any controller recovers
PUSH_SECONDS = 0.2


class _Observer:
    """The simulation's per-``every``-ticks hook: a video frame (or None without a camera), a progress
    update and the state for a live viewer."""

    def __init__(self, camera: _FollowCamera | None, bar: Progress, seconds_per_call: float,
                 publisher: ScenePublisher | None = None) -> None:  # fmt: skip
        self.camera, self.bar, self.seconds_per_call, self.publisher = camera, bar, seconds_per_call, publisher
        self._start: float | None = None  # wall clock at the first call: a live stream is paced to real time

    def __call__(self, robot: Any) -> np.ndarray | None:
        self.bar(self.seconds_per_call)
        if self.publisher is not None:
            now = time.perf_counter()
            if self._start is None:
                self._start = now - robot.time()
            ahead = robot.time() - (now - self._start)
            if ahead > 0.0:  # a viewer follows the robot at the speed it would move
                time.sleep(ahead)
            base = robot.base_state()
            contacts = robot.description.contacts
            wrenches = [robot.contact_wrench(c.link) for c in contacts]
            self.publisher.send(robot.time(), robot.joint_positions(), robot.joint_efforts(), base.position, base.quaternion,
                                np.array([w.in_contact for w in wrenches]), np.array([w.force for w in wrenches]).reshape(-1, 3))
        return self.camera(robot) if self.camera is not None else None


class _FollowCamera:
    """Offscreen frames from a camera that follows the base (an offscreen GL backend, probed when first used)."""

    def __init__(self, size: tuple[int, int] = (480, 640)) -> None:
        self.size = size
        self._renderer = None
        self._camera = None

    def __call__(self, robot: Any) -> np.ndarray:
        model, data = robot.model, robot.data
        if self._renderer is None:
            self._renderer = offscreen_renderer(model, *self.size)  # (RenderingUnavailableError without GL)
            self._camera = mujoco.MjvCamera()
            self._camera.distance, self._camera.azimuth, self._camera.elevation = 2.8, 135.0, -15.0
        self._camera.lookat[:] = robot.base_state().position * np.array([1.0, 1.0, 0.0]) + np.array([0.0, 0.0, 0.6])
        self._renderer.update_scene(data, camera=self._camera)
        return self._renderer.render()


def run_walk(
    robot: str = "g1",
    command: tuple[float, float, float] = (0.4, 0.0, 0.0),
    seconds: float = 20.0,
    *,
    push: float = 0.0,
    push_time: float = 3.0,
    push_direction_deg: float = 180.0,
    video: str | None = None,
    seed: int | None = None,
    progress: bool = False,
    foxglove_port: int | None = None,
    plant: PlantSpec = None,
) -> tuple[WalkRun, str | None]:
    """Walk ``robot`` at ``command`` for ``seconds``; an optional push of ``push`` N for 0.2 s.
    ``progress``: a bar of simulated seconds on stderr. ``foxglove_port``: stream the robot to
    Foxglove on this loopback port at 30 Hz, paced to real time, from a publisher process.
    ``plant``: the simulated plant (:func:`giwbc.plants.resolve_plant`; default the description's model).
    ConfigError for a robot that cannot walk or a push outside the run."""
    description = load(robot)
    check_walker_robot(description)
    check_push(push, push_time, seconds)
    pushes = (Push(push_time, push, math.radians(push_direction_deg), PUSH_SECONDS),) if push > 0 else ()
    camera = _FollowCamera() if video else None
    every = max(1, int(round((1.0 / VIDEO_FPS if video else 1.0 / LIVE_HZ if foxglove_port else PROGRESS_S) / description.timestep)))
    publisher = ScenePublisher(description, port=foxglove_port, rate=LIVE_HZ) if foxglove_port is not None else None
    try:
        with Progress(seconds, "walk", unit="sim s", enabled=progress) as bar:
            wanted = camera is not None or bar.enabled or publisher is not None
            hook = _Observer(camera, bar, every * description.timestep, publisher) if wanted else None
            run = simulate_walk(description, command, seconds, pushes=pushes, render=hook, render_every=every if hook else 0, seed=seed,
                                plant=plant)
    finally:
        if publisher is not None:
            publisher.close()
    if not video:
        run.frames.clear()  # the progress hook's placeholders
    written = None
    if video:
        written = str(write_video(video, run.frames, fps=1.0 / (every * description.timestep)))
    return run, written


def check_walker_robot(description: RobotDescription) -> None:
    """ConfigError unless the robot has a floating base and one foot contact per side (left_*, right_*)."""
    if not description.floating_base:
        raise ConfigError(f"robot {description.name!r} has a fixed base: walking needs a floating-base robot with two feet (e.g. g1)")
    names = [c.name for c in description.contacts]
    if sorted(n.split("_")[0] for n in names if n.startswith(("left", "right"))) != ["left", "right"]:
        raise ConfigError(f"robot {description.name!r} cannot walk: it needs one foot contact per side named left_*/right_*, "
                          f"it has {names}")


def check_push(force: float, start: float, seconds: float) -> None:
    """ConfigError for a push that would not happen within the run (a silently missing push reads as a recovery)."""
    if not (math.isfinite(force) and 0.0 <= force <= MAX_PUSH):
        raise ConfigError(f"the push must be in [0, {MAX_PUSH:g}] N, got {force}")
    if force > 0 and not (math.isfinite(start) and 0.0 <= start and start + PUSH_SECONDS <= seconds):
        raise ConfigError(f"the push at t = {start:g} s for {PUSH_SECONDS} s must end within the run's {seconds:g} s "
                          "(raise --seconds or lower --push-time)")


def followed_command(command: tuple[float, float, float]) -> tuple[tuple[float, float, float], list[str]]:
    """The command the walker follows (clamped to the gait's limits) and a note per clamped component."""
    clamped = FootstepPlanner(WalkerConfig().gait).clamp(VelocityCommand(*command))
    followed = clamped.command
    return (followed.vx, followed.vy, followed.yaw_rate), list(clamped.notes)


def _number(value: float) -> float | None:
    """JSON has no NaN: None for a figure that does not exist (e.g. no steps to average)."""
    return round(float(value), 4) if math.isfinite(value) else None


def summary(run: WalkRun, command: tuple[float, float, float], wall: float) -> dict[str, Any]:
    ticks = run.tick_seconds * 1e6
    single = ticks[run.single_support_ticks]
    followed, clamped = followed_command(command)
    return {
        "command": list(command),
        "command_followed": [round(x, 4) for x in followed],
        "command_clamped": bool(clamped),
        "seconds": round(run.seconds, 3),
        "fell": run.fell,
        "fall_time": run.fall_time,
        "steps": run.steps,
        "recovery_steps": run.recovery_steps,
        "mean_velocity": [_number(x) for x in run.mean_velocity],
        "mean_yaw_rate": _number(run.mean_yaw_rate),
        # Two definitions (giwbc.locomotion.tracking): per-step averages (touch-down to touch-down) and every tick's
        # instantaneous base velocity in the heading frame (mjlab's track_lin_vel_xy), over the same span.
        "tracking_rms_per_step": _number(run.tracking_rms),
        "yaw_rate_rms_per_step": _number(run.yaw_rate_rms),
        **{key: _number(value) for key, value in run.per_tick.summary().items() if key != "ticks"},
        "distance": [round(float(x), 3) for x in run.distance],
        "early_touchdowns": run.early_touchdowns,
        "late_touchdowns": run.late_touchdowns,
        "wbc_failures": run.wbc_failures,
        "wbc_tick_median_us": round(float(np.median(ticks)), 1) if len(ticks) else None,
        "wbc_tick_single_support_median_us": round(float(np.median(single)), 1) if len(single) else None,
        "notes": run.notes,
        "wall_seconds": round(wall, 2),
    }


def add_walk_command(commands: Any) -> None:
    """Add ``giwbc walk`` to an argparse subparsers object."""
    parser = add_command(commands, "walk", "walk the robot in MuJoCo from a velocity command (model-based stepping on the WBC)")
    speed = number(-MAX_SPEED, MAX_SPEED, unit="m/s")
    parser.add_argument("--robot", default="g1", help=ROBOT_HELP + "; it must have a floating base and two feet")
    parser.add_argument("--vx", type=speed, default=0.4, help=f"forward velocity, m/s, in [-{MAX_SPEED:g}, {MAX_SPEED:g}] (clamped to the gait's limits, and said so)")
    parser.add_argument("--vy", type=speed, default=0.0, help=f"lateral velocity, m/s, in [-{MAX_SPEED:g}, {MAX_SPEED:g}] (clamped to the gait's limits)")
    parser.add_argument("--yaw-rate", type=number(-MAX_SPEED, MAX_SPEED, unit="rad/s"), default=0.0,
                        help=f"turning rate, rad/s, in [-{MAX_SPEED:g}, {MAX_SPEED:g}] (clamped to the gait's limits)")
    parser.add_argument("--seconds", type=seconds(MAX_SECONDS), default=20.0, help=f"simulated seconds, in (0, {MAX_SECONDS:g}]")
    parser.add_argument("--push", type=number(0.0, MAX_PUSH, unit="N"), default=0.0,
                        help=f"push the pelvis with this force, N, in [0, {MAX_PUSH:g}], for {PUSH_SECONDS} s (0: no push)")
    parser.add_argument("--push-time", type=seconds(MAX_SECONDS, allow_zero=True), default=3.0,
                        help="when the push starts, simulated s (the push must end within --seconds)")
    parser.add_argument("--push-direction", type=number(-360.0, 360.0, unit="deg"), default=180.0,
                        help="push direction, degrees in the world frame (0: forward, 180: backward)")
    parser.add_argument("--seed", type=seed(), default=None, help="perturb the initial state from this seed (default: no perturbation)")
    parser.add_argument("--plant", default=None, help="the simulated plant: a variant of robots/<robot>/plants (e.g. point_feet), a "
                        "variant .toml or a vendor's MJCF file (.xml) of the robot, checked against its description (default: its own model)")
    parser.add_argument("--video", default=None, help="write a video (.mp4 or .gif); needs an offscreen GL library (libegl1 or libosmesa6)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--foxglove", action="store_true",
                        help="stream the robot in 3D to Foxglove over a loopback WebSocket, paced to real time (needs foxglove-sdk)")
    parser.add_argument("--foxglove-port", type=port(), default=DEFAULT_PORT, help="the WebSocket's TCP port")
    add_progress_argument(parser)
    parser.set_defaults(run=run_walk_command)


def _figure(value: float | None, unit: str) -> str:
    return "n/a" if value is None else f"{value} {unit}"


def _speed_text(values: list[float | None]) -> str:
    return "n/a (no complete step)" if any(v is None for v in values) else f"{values} m/s"


def run_walk_command(args: argparse.Namespace) -> int:
    command = (args.vx, args.vy, args.yaw_rate)
    if not all(math.isfinite(x) for x in command):
        raise ConfigError(f"the velocity command must be finite, got {command}")
    check_walker_robot(load(args.robot))  # before a Foxglove server or a video starts
    plant = resolve_plant(load(args.robot), args.plant) if getattr(args, "plant", None) else None  # refused here, in one line
    check_push(args.push, args.push_time, args.seconds)
    if args.video is not None and not args.video.lower().endswith((".mp4", ".gif")):
        raise ConfigError(f"--video {args.video}: expected a .mp4 or .gif file")  # before the walk, not after it
    if args.foxglove:
        require_foxglove()
        print(f"Foxglove: open a connection to ws://{HOST}:{args.foxglove_port}", file=sys.stderr)
    started = time.perf_counter()
    run, video = run_walk(args.robot, command, args.seconds, push=args.push, push_time=args.push_time,
                          push_direction_deg=args.push_direction, video=args.video, seed=args.seed,
                          progress=wants_progress(args), foxglove_port=args.foxglove_port if args.foxglove else None,
                          plant=plant)
    result = summary(run, command, time.perf_counter() - started)
    if video:
        result["video"] = video
    if plant is not None:
        result["plant"] = plant.name
    if args.json:
        print(json.dumps(result))
    else:
        for note in run.notes:
            print(f"note: {note}")
        state = f"FELL at {run.fall_time:.2f} s" if run.fell else "no fall"
        followed = tuple(result["command_followed"])
        asked = f" (clamped to the gait's limits from {command})" if result["command_clamped"] else ""
        print(f"{args.robot}: walked {run.seconds:.1f} s at command (vx, vy, yaw rate) = {followed} m/s, m/s, rad/s{asked}: {state}")
        yaw = result["mean_yaw_rate"]
        print(f"  speed {_speed_text(result['mean_velocity'])} (heading frame, per-step averages), yaw rate "
              f"{'n/a' if yaw is None else f'{yaw} rad/s'}")
        print(f"  tracking error, per-step averages: xy RMS {_figure(result['tracking_rms_per_step'], 'm/s')}, yaw rate RMS "
              f"{_figure(result['yaw_rate_rms_per_step'], 'rad/s')}; per tick (instantaneous, heading frame): xy RMS "
              f"{_figure(result['tracking_rms_per_tick_heading_xy'], 'm/s')}, mean abs "
              f"{_figure(result['tracking_mean_abs_per_tick_heading_xy'], 'm/s')}, yaw rate RMS "
              f"{_figure(result['yaw_rate_rms_per_tick'], 'rad/s')}, mean abs {_figure(result['yaw_rate_mean_abs_per_tick'], 'rad/s')}")
        if args.push > 0 and not run.fell and run.seconds < args.push_time + PUSH_SECONDS + SETTLE_AFTER_PUSH_S - 1e-9:
            print(f"  note: the run ended {run.seconds - args.push_time - PUSH_SECONDS:.2f} s after the push: not judged a recovery "
                  f"(that takes {SETTLE_AFTER_PUSH_S:g} s up after the push)")
        print(f"  {run.steps} steps ({run.recovery_steps} for push recovery), distance {result['distance']} m, "
              f"WBC failures {run.wbc_failures}, WBC tick median {result['wbc_tick_median_us']} µs")
        if video:
            print(f"  video: {video}")
    return 1 if run.fell else 0
