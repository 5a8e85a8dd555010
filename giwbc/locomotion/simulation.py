"""Closed-loop runs of the walking controller in MuJoCo: walks, pushes, and their figures.

One function, :func:`simulate_walk`, used by the tests, ``giwbc walk`` and
``benchmarks/locomotion.py``: the G1 (or any description with two feet) starts standing, the
velocity command is applied from ``command_start``, optional pushes act on the base link, and the
run stops early at a fall. Ground truth comes from MuJoCo (base pose and velocity), not from the
controller.

**Velocity tracking** (as the issue defines it, cf. mjlab's velocity command metrics): the base
xy velocity averaged over each step (touch-down to touch-down), expressed in the heading frame,
against the command; the RMS over the steps after the first two (the start-up transient).
Beside it, the same span scored **per tick** in the heading frame (:mod:`giwbc.locomotion.tracking`,
mjlab's ``track_lin_vel_xy``): the instantaneous base velocity at every controller tick, the
gait's sway within a step included.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from giwbc.control.balance import make_balance_controller
from giwbc.locomotion.tracking import TickTracking, per_tick_tracking
from giwbc.locomotion.walker import Phase, WalkerConfig, WalkingController
from giwbc.plants import PlantSpec, plant_robot
from giwbc.robot.description import RobotDescription
from giwbc.robot.mujoco_model import foot_sensor_names
from giwbc.robot.mujoco_robot import MujocoRobot

FALL_HEIGHT_FRACTION = 0.65  # fallen: base below this fraction of its standing height ...
FALL_TILT_DEG = 45.0  # ... or tilted beyond this


@dataclass(frozen=True)
class Push:
    """A horizontal force on the base link: ``force`` N for ``duration`` s from ``start``, towards ``direction`` (rad, world)."""

    start: float
    force: float
    direction: float
    duration: float = 0.2

    @property
    def impulse(self) -> float:
        return self.force * self.duration

    def vector(self) -> np.ndarray:
        return self.force * np.array([math.cos(self.direction), math.sin(self.direction), 0.0])


@dataclass
class WalkRun:
    """What a run did (MuJoCo ground truth) and what the controller counted."""

    seconds: float  # simulated before the end or the fall
    fell: bool
    fall_time: float | None
    steps: int
    recovery_steps: int
    early_touchdowns: int
    late_touchdowns: int
    wbc_failures: int
    distance: np.ndarray  # base xy displacement over the command period, m
    mean_velocity: np.ndarray  # heading frame (vx, vy), m/s, over the steps after the first two
    mean_yaw_rate: float
    step_velocities: np.ndarray  # (steps, 3): per-step average (vx, vy, yaw rate), heading frame
    tracking_rms: float  # RMS over steps of ‖v_step − v_cmd‖ (xy), m/s
    yaw_rate_rms: float
    final_tilt: float  # rad, of the base at the end
    per_tick: TickTracking = field(default_factory=lambda: per_tick_tracking(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(3)))
    # ^ the same span as tracking_rms (3rd to last touch-down), every tick, instantaneous velocity in the heading frame
    tick_seconds: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))  # WBC tick wall times
    single_support_ticks: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, dtype=bool))
    switch_ticks: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, dtype=bool))
    notes: list[str] = field(default_factory=list)
    frames: list = field(repr=False, default_factory=list)


def perturbed_initial_state(robot: MujocoRobot, rng: np.random.Generator, joint_std: float = 0.01, velocity_std: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """The default standing state (Pinocchio convention) with joint positions perturbed by
    ``joint_std`` rad and the base's linear velocity by ``velocity_std`` m/s (Gaussian): seeded runs
    differ from the first tick."""
    q, v = robot.generalized_state()
    q = q.copy()
    v = v.copy()
    q[7:] += rng.normal(0.0, joint_std, len(q) - 7)
    v[:2] += rng.normal(0.0, velocity_std, 2)
    return q, v


def _yaw(rotation: np.ndarray) -> float:
    return math.atan2(rotation[1, 0], rotation[0, 0])


def simulate_walk(
    description: RobotDescription,
    command: tuple[float, float, float] = (0.0, 0.0, 0.0),
    seconds: float = 10.0,
    *,
    pushes: tuple[Push, ...] = (),
    step_in_place: bool = False,
    command_start: float = 0.5,
    config: WalkerConfig | None = None,
    stepping: bool = True,
    render: object | None = None,
    render_every: int = 0,
    seed: int | None = None,
    plant: PlantSpec = None,
    observe: Callable[[MujocoRobot, WalkingController], None] | None = None,
) -> WalkRun:
    """Run the walking controller (``stepping=False``: the feet-in-place balance controller of
    :mod:`giwbc.control.balance`, for comparison; the command is then ignored) in MuJoCo; stop at ``seconds`` or at a fall. ``render(robot)`` is called every
    ``render_every`` ticks when given (video frames are appended to ``WalkRun.frames``). ``plant``: the
    simulated plant (:func:`giwbc.plants.resolve_plant`: a variant name, an MJCF file, an MjModel;
    default the description's own); ``observe(robot, controller)`` is called after every physics step."""
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds must be > 0, got {seconds}")
    robot = MujocoRobot(description) if plant is None else plant_robot(description, plant)
    if seed is not None:
        robot.reset(*perturbed_initial_state(robot, np.random.default_rng(seed)))
    controller = WalkingController(description, config)
    q, v = robot.generalized_state()
    controller.reset(q)
    baseline = None
    if not stepping:  # the feet-in-place balance controller, untouched (the baseline of the issue)
        baseline = make_balance_controller(description)
        baseline.reset(q)
    touch = {side: foot_sensor_names(contact.name)["touch"] for side, contact in controller.contacts.items()}
    dt = description.timestep
    base0 = robot.base_state()
    height0 = float(base0.position[2])
    fell, fall_time = False, None
    ticks = int(round(seconds / dt))
    timings = np.zeros(ticks)
    single = np.zeros(ticks, dtype=bool)
    switches = np.zeros(ticks, dtype=bool)
    touchdowns: list[tuple[float, np.ndarray, float]] = []
    base_velocity = np.zeros((ticks, 2))  # world xy, after each tick's physics step
    base_yaw = np.zeros(ticks)
    base_yaw_rate = np.zeros(ticks)  # world z angular velocity: the heading frame's
    start_xy: np.ndarray | None = None
    notes: list[str] = []
    frames: list = []
    last_steps = 0
    previous_phase = Phase.STAND
    n = 0
    for i in range(ticks):
        t = i * dt
        if command_start is not None and abs(t - command_start) < 0.5 * dt:
            notes.extend(controller.set_command(*command, step_in_place=step_in_place))
            start_xy = robot.base_state().position[:2].copy()
        force = np.zeros(3)
        for push in pushes:
            if push.start <= t < push.start + push.duration:
                force += push.vector()
        robot.set_external_wrench(description.base_link, force)
        if baseline is None:
            # The walker's own loop (its step(robot) does the same through Robot.contact_wrench;
            # MuJoCo's foot touch sensors give the normal forces at a fraction of the cost).
            q, v = robot.generalized_state()
            forces = {side: float(robot.sensor(name)[0]) for side, name in touch.items()}
            result = controller.update(q, v, robot.time(), forces)
            robot.set_joint_torques(result.tau)
        else:
            result = baseline.step(robot)
        if not stepping:
            controller.state.phase = Phase.STAND
        timings[i] = result.timings.total
        phase = controller.state.phase
        single[i] = phase is Phase.SINGLE
        switches[i] = phase is not previous_phase
        previous_phase = phase
        robot.step()
        n = i + 1
        if observe is not None:
            observe(robot, controller)
        base = robot.base_state()
        base_velocity[i] = base.linear_velocity[:2]
        base_yaw[i] = _yaw(base.rotation)
        base_yaw_rate[i] = base.angular_velocity[2]
        if controller.state.steps != last_steps:
            last_steps = controller.state.steps
            touchdowns.append((t, base.position[:2].copy(), _yaw(base.rotation)))
        if render is not None and render_every and i % render_every == 0:
            frames.append(render(robot))  # type: ignore[operator]
        tilt = math.degrees(math.acos(min(max(base.rotation[2, 2], -1.0), 1.0)))
        if base.position[2] < FALL_HEIGHT_FRACTION * height0 or tilt > FALL_TILT_DEG:
            fell, fall_time = True, t
            break
    state = controller.state
    end = robot.base_state()
    distance = end.position[:2] - (start_xy if start_xy is not None else base0.position[:2])
    # Per-step velocities (heading frame of the step's start), after the first two steps.
    rows = []
    for (t0, p0, y0), (t1, p1, y1) in zip(touchdowns[2:], touchdowns[3:]):
        c, s = math.cos(y0), math.sin(y0)
        dp = (p1 - p0) / (t1 - t0)
        rows.append([c * dp[0] + s * dp[1], -s * dp[0] + c * dp[1], math.remainder(y1 - y0, 2 * math.pi) / (t1 - t0)])
    steps = np.array(rows).reshape(-1, 3)
    cmd = np.array([controller.command.vx, controller.command.vy, controller.command.yaw_rate])
    if len(steps):
        errors = steps[:, :2] - cmd[:2]
        tracking = float(np.sqrt(np.mean(np.sum(errors**2, axis=1))))
        yaw_rms = float(np.sqrt(np.mean((steps[:, 2] - cmd[2]) ** 2)))
        mean_velocity, mean_yaw = steps[:, :2].mean(axis=0), float(steps[:, 2].mean())
    else:
        tracking, yaw_rms, mean_velocity, mean_yaw = math.nan, math.nan, np.full(2, math.nan), math.nan
    # Per tick over the span of the per-step figure: the ticks after the 3rd touch-down's up to the last's.
    scored = np.zeros(n, dtype=bool)
    if len(steps):
        tick = np.arange(n)
        scored = (tick > round(touchdowns[2][0] / dt)) & (tick <= round(touchdowns[-1][0] / dt))
    per_tick = per_tick_tracking(base_velocity[:n][scored], base_yaw[:n][scored], base_yaw_rate[:n][scored], cmd)
    notes.extend(n for n in state.notes if n not in notes)
    return WalkRun(
        n * dt, fell, fall_time, state.steps, state.recovery_steps, state.early_touchdowns, state.late_touchdowns,
        controller.wbc.failures, distance, mean_velocity, mean_yaw, steps, tracking, yaw_rms,
        math.acos(min(max(float(end.rotation[2, 2]), -1.0), 1.0)), per_tick,
        timings[:n], single[:n], switches[:n], notes, frames,
    )
