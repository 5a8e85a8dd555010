"""Walking on velocity commands: the policy adds residuals to a model-based walker.

Beneath the action runs :class:`~giwbc.locomotion.walker.WalkingController` (footstep planner,
DCM reference and controller, online step adapter, swing trajectories, contact schedule) on the
QP whole-body controller, at the controller rate, from the measured ``(q, v)`` and foot forces of
the :class:`~giwbc.robot.interface.Robot` interface. Any description with a floating base and
two feet named ``left_*`` / ``right_*`` works.

Velocity commands ``(vx, vy, yaw_rate)`` (body frame) are drawn at reset for the whole episode
from :class:`CommandRanges` (uniform per component, or standing still with some probability),
each held for a uniform random time, all from the runtime's seeded generator.

Action blocks (``residuals=``; each entry in [-1, 1] times its scale):

- ``step``: offsets to the next footstep (x, y in the stance sole's frame, m) and to the single
  support duration (s), on top of the plan and the step adapter's correction; the landing spot
  stays in the step adapter's landing box and the duration in ``[min_swing, max_swing]``;
- ``com``: offsets of the DCM reference (x, y in the heading frame; a CoM offset in steady state)
  and of the CoM height (m);
- ``orientation``: pelvis roll, pitch, yaw offsets about the walker's heading (rad);
- ``hip``: one entry, added to the gain of the walker's hip strategy (rad of pelvis roll into the
  fall per m of lateral DCM error, ``WalkerConfig.hip_roll_gain``): a feedback the walker applies
  every controller tick, within its ``hip_roll_max`` and its own ``hip_gate``, where a policy's
  orientation residual is held for an agent step;
- ``torque`` (off unless named): one entry per leg joint (hips, knees, ankles: joints named
  ``*hip*``, ``*knee*``, ``*ankle*``), a joint torque added to the WBC's output at every controller
  tick, a full entry being ``scales.torque`` (default 5 %) of that joint's effort limit (the actuators
  clip the sum to the limit): a delta action where the plant's joints differ from the model
  (friction, armature, lag) that no reference of the walker reaches. A residual on the WBC's CoP /
  contact-force references is not a block: the ``com`` block's DCM offset moves the CoP the DCM
  controller asks for, and the walker has no other hook for it.

The zero action is the walker alone, bit for bit. With ``residual_gate=(start, full)`` (m) the
residuals act in proportion to ``clip((|ξ − ξ_ref| − start) / (full − start), 0, 1)`` of the
walker's DCM error: none while the walker tracks its DCM reference (undisturbed walking is the
walker alone, whatever the policy outputs), in full once a push has moved the DCM by ``full``.
The ``hip`` gain is not scaled by it: the hip strategy's gate already does that to its roll.

Observation (what the robot and its walker know): gravity in the IMU frame, IMU angular rate,
joint positions minus the default pose, joint velocities, the base velocity in the heading frame
(vx, vy, yaw rate), the command, the gait phase (stand / double / single one-hot, stance side,
progress), the next footstep relative to the base (x, y, yaw), the DCM error (heading frame), the
previous action. Reward: alive + velocity tracking (xy and yaw rate) + uprightness, minus effort,
action-rate, optionally joints near their limits, and a fall penalty. Terminates when the pelvis
drops or tilts too far (or, with ``joint_limit_margin``, a joint passes the deployment's soft limits).

With a state estimator in the runtime's loop (``sim2real={"estimator": ...}``) the walker and the
observation run on the estimated base, as deployed, and the contact plan goes to the estimator;
reward, termination and info read the simulated truth (:attr:`Task.truth`).
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from gymnasium import spaces

from giwbc.locomotion.residuals import check_error_gate, error_gate
from giwbc.locomotion.walker import Phase, WalkingController
from giwbc.locomotion.walker_config import walker_config
from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import BaseState, quat_to_matrix
from giwbc.tasks.floating_base import ANGULAR_VELOCITY_SCALE, JOINT_VELOCITY_SCALE, FloatingBaseTask
from giwbc.tasks.task import ActionBlock, ResidualLayout

BLOCKS = ("step", "com", "orientation", "hip", "torque")
_SIZES = {"step": 3, "com": 3, "orientation": 3, "hip": 1, "torque": 1}  # torque: one scale for all leg joints
TORQUE_JOINTS = ("*hip*", "*knee*", "*ankle*")  # fnmatch patterns of the joints the torque block acts on
_PHASES = (Phase.STAND, Phase.DOUBLE, Phase.SINGLE)


def _pair(value: Any, name: str) -> tuple[float, float]:
    low, high = (float(v) for v in value)
    if not (math.isfinite(low) and math.isfinite(high) and low <= high):
        raise ValueError(f"{name} must be a finite range (low <= high), got {value}")
    return low, high


@dataclass(frozen=True)
class CommandRanges:
    """Velocity commands of an episode: each held ``interval`` s (uniform), zero with
    probability ``standing``, else uniform in ``vx``, ``vy`` (m/s) and ``yaw_rate`` (rad/s)."""

    vx: tuple[float, float] = (-0.1, 0.4)
    vy: tuple[float, float] = (-0.1, 0.1)
    yaw_rate: tuple[float, float] = (-0.3, 0.3)
    standing: float = 0.15
    interval: tuple[float, float] = (2.0, 4.0)
    horizon: float = 60.0  # s of commands drawn at reset

    def __post_init__(self) -> None:
        for name in ("vx", "vy", "yaw_rate", "interval"):
            object.__setattr__(self, name, _pair(getattr(self, name), name))
        if not (0.0 <= self.standing <= 1.0):
            raise ValueError(f"standing must be a probability, got {self.standing}")
        if self.interval[0] <= 0 or not (0 < self.horizon < math.inf):
            raise ValueError("command interval and horizon must be > 0")

    def draw(self, rng: np.random.Generator) -> list[tuple[float, tuple[float, float, float]]]:
        """``[(start time, (vx, vy, yaw_rate)), ...]`` covering ``horizon`` s."""
        schedule, t = [], 0.0
        while t < self.horizon:
            if rng.uniform() < self.standing:
                command = (0.0, 0.0, 0.0)
            else:
                command = tuple(float(rng.uniform(*r)) for r in (self.vx, self.vy, self.yaw_rate))
            schedule.append((t, command))
            t += float(rng.uniform(*self.interval))
        return schedule  # type: ignore[return-value]


@dataclass(frozen=True)
class WalkRewards:
    """Reward weights and widths of :class:`G1Walk` (per agent step)."""

    alive: float = 1.0
    tracking: float = 1.0
    tracking_width: float = 0.25  # m/s of xy velocity error at which the term falls to 1/e
    yaw_tracking: float = 0.5
    yaw_tracking_width: float = 0.5  # rad/s
    upright: float = 0.5
    upright_width: float = 0.1  # rad
    effort: float = 0.05  # times the mean squared effort / effort limit
    action_rate: float = 0.05  # times the mean squared action change
    # Times the mean squared action, i.e. the residual itself (its zero is the walker alone): keeps the
    # policy at the walker where the walker does well (residual RL's usual prior; the estimator-in-the-
    # loop runs of 26 Nov drifted off it and lost 16 % of undisturbed episodes the walker walks). 0: off.
    action: float = 0.0
    fall: float = 20.0
    # Per rad a joint is beyond `joint_limit_band` of its half range from the middle, summed over the
    # joints (legged_gym's dof_pos_limits): a dense signal before the deployment's soft limits (which
    # `joint_limit_margin` turns into a fall) — the G1's ankle rolls reach 0.17-0.22 of their 0.26 rad
    # in lateral and turning steps. 0: off.
    joint_limits: float = 0.0
    joint_limit_band: float = 0.8

    def __post_init__(self) -> None:
        if not (0.0 < self.joint_limit_band <= 1.0):
            raise ValueError(f"joint_limit_band must be in (0, 1], got {self.joint_limit_band}")
        for name in ("joint_limits", "action"):
            value = getattr(self, name)
            if not (value >= 0.0 and math.isfinite(value)):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")


@dataclass(frozen=True)
class WalkScales:
    """Physical size of a full (±1) action entry, per block entry."""

    step: tuple[float, float, float] = (0.1, 0.08, 0.1)  # m, m, s
    com: tuple[float, float, float] = (0.03, 0.03, 0.02)  # m
    orientation: tuple[float, float, float] = (0.1, 0.1, 0.1)  # rad
    hip: tuple[float] = (8.0,)  # rad/m of hip-strategy gain
    torque: tuple[float] = (0.05,)  # fraction of each leg joint's effort limit

    def __post_init__(self) -> None:
        for name in BLOCKS:
            value, size = getattr(self, name), _SIZES[name]
            values = tuple(float(v) for v in (value if isinstance(value, (list, tuple)) else (value,) * size))
            if len(values) != size:
                raise ValueError(f"scale {name} needs {size} entries, got {value}")
            object.__setattr__(self, name, values)
        if not 0.0 <= self.torque[0] <= 0.25:
            raise ValueError(f"scale torque is a fraction of the effort limit in [0, 0.25], got {self.torque[0]}")


def torque_joints(description: RobotDescription) -> np.ndarray:
    """Indices (description order) of the joints the ``torque`` block acts on: the actuated leg joints."""
    names = description.joint_names
    return np.array([i for i, name in enumerate(names)
                     if description.actuated[i] and any(fnmatch.fnmatchcase(name, p) for p in TORQUE_JOINTS)], dtype=int)


def _layout(scales: WalkScales, names: Sequence[str], description: RobotDescription) -> ResidualLayout:
    names = tuple(names)
    if not names or len(set(names)) != len(names) or set(names) - set(BLOCKS):
        raise ValueError(f"residuals must be distinct names among {BLOCKS}, got {list(names)}")
    labels = {"step": ("x", "y", "duration"), "com": ("x", "y", "z"), "orientation": ("roll", "pitch", "yaw"), "hip": ("roll_gain",)}
    blocks = []
    for name in BLOCKS:
        if name not in names:
            continue
        if name == "torque":
            legs = torque_joints(description)
            if not len(legs):
                raise ValueError(f"residual block 'torque': robot {description.name!r} has no actuated joint matching {list(TORQUE_JOINTS)}")
            effort = np.asarray(description.effort_limits, dtype=float)[legs]
            blocks.append(ActionBlock(name, len(legs), tuple(scales.torque[0] * effort), tuple(description.joint_names[i] for i in legs)))
        else:
            blocks.append(ActionBlock(name, _SIZES[name], getattr(scales, name), labels[name]))
    return ResidualLayout(blocks)


def _yaw(quaternion: np.ndarray) -> float:
    x, y, z, w = quaternion
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class G1Walk(FloatingBaseTask):
    """Track velocity commands: residual actions over the walker (see the module docstring)."""

    def __init__(
        self,
        description: RobotDescription,
        *,
        residuals: Sequence[str] | None = None,
        scales: WalkScales | dict[str, Any] | None = None,
        rewards: WalkRewards | dict[str, float] | None = None,
        commands: CommandRanges | dict[str, Any] | None = None,
        initial_joint_noise: float = 0.02,
        min_height_ratio: float = 0.7,
        max_tilt: float = 0.7,
        walker: dict[str, Any] | str | None = None,  # WalkerConfig fields (scalars), or a preset: "deployment"
        joint_limit_margin: float | None = None,
        wbc_options: dict[str, Any] | None = None,
        residual_gate: Sequence[float] | None = None,  # (start, full) m of DCM error: see the module docstring
    ) -> None:
        super().__init__()
        if not description.floating_base or len(description.contacts) != 2:
            raise ValueError(f"G1Walk needs a floating-base robot with two feet, got {description.name!r}")
        self.description = description
        self.scales = WalkScales(**scales) if isinstance(scales, dict) else scales or WalkScales()
        self.rewards = WalkRewards(**rewards) if isinstance(rewards, dict) else rewards or WalkRewards()
        self.commands = CommandRanges(**commands) if isinstance(commands, dict) else commands or CommandRanges()
        self.layout = _layout(self.scales, residuals or ("step",), description)
        self._torque_joints = torque_joints(description)
        self._torque = np.zeros(description.dofs)  # the torque block's residual, N m (description order)
        self._torque_on = False
        self.initial_joint_noise = float(initial_joint_noise)
        self.max_tilt = float(max_tilt)
        # Deployment's safety layer stops the robot when a joint leaves its limits moved inward by
        # its soft-limit margin (giwbc.hal.safety, 0.02 rad): with a margin here, an episode ends
        # there too, as a fall, so a policy learns to stay where it can be deployed.
        self.joint_limit_margin = None if joint_limit_margin is None else float(joint_limit_margin)
        if self.joint_limit_margin is not None and not 0.0 <= self.joint_limit_margin < 0.5:
            raise ValueError(f"joint_limit_margin must be in [0, 0.5) rad or None, got {joint_limit_margin}")
        lower, upper = description.position_limits
        margin = self.joint_limit_margin or 0.0
        self._soft_lower, self._soft_upper = np.asarray(lower, dtype=float) + margin, np.asarray(upper, dtype=float) - margin
        middle, half = 0.5 * (np.asarray(upper, float) + np.asarray(lower, float)), 0.5 * (np.asarray(upper, float) - np.asarray(lower, float))
        finite = np.isfinite(middle) & np.isfinite(half)
        band = self.rewards.joint_limit_band * half
        self._band_lower = np.where(finite, middle - band, -np.inf)
        self._band_upper = np.where(finite, middle + band, np.inf)
        self._terminated: tuple[float, bool] | None = None
        self.residual_gate = None if residual_gate is None else check_error_gate(residual_gate, "residual_gate")
        config = walker_config(walker)
        if wbc_options:  # the WBC's options (BalanceConfig fields) over the walker's own
            config = replace(config, balance=replace(config.balance, **wbc_options))
        self.walker = WalkingController(description, config, description.pinocchio_model)
        self._plans = self.walker.contact_plans([c.link for c in description.contacts])  # an estimator's contact order
        self.q0 = description.default_configuration()
        self.min_height = min_height_ratio * float(self.q0[2])
        self.default_positions = description.default_positions
        self._effort_scale = np.where(description.effort_limits > 0, 1.0 / np.maximum(description.effort_limits, 1e-9), 0.0)
        self.schedule: list[tuple[float, tuple[float, float, float]]] = []
        self._next_command = 0
        self.command = np.zeros(3)
        self.last_action = np.zeros(self.layout.size)
        self.previous_action = np.zeros(self.layout.size)
        self._base: tuple[float, BaseState] | None = None
        self.result: Any = None

    # --- spaces ---------------------------------------------------------------------------
    def create_spaces(self) -> tuple[spaces.Box, spaces.Box]:
        if tuple(self.robot.joint_names) != self.description.joint_names:
            raise ValueError(f"robot joints {self.robot.joint_names} differ from the description's")
        n, m = self.robot.dofs, self.layout.size
        high = np.concatenate([np.ones(3), np.full(3 + 2 * n, 10.0), np.full(3 + 3, 10.0), np.ones(5), np.full(5, 10.0), np.ones(m)])
        return self.layout.space(), spaces.Box(-high.astype(np.float32), high.astype(np.float32), dtype=np.float32)

    def observation_names(self) -> tuple[str, ...]:
        joints = self.description.joint_names
        return (
            *(f"gravity_imu/{a}" for a in "xyz"),
            *(f"angular_velocity_imu/{a}" for a in "xyz"),
            *(f"joint_position_offset/{j}" for j in joints),
            *(f"joint_velocity/{j}" for j in joints),
            "base_velocity/vx", "base_velocity/vy", "base_velocity/yaw_rate",
            "command/vx", "command/vy", "command/yaw_rate",
            "phase/stand", "phase/double", "phase/single", "phase/stance_side", "phase/progress",
            "next_footstep/x", "next_footstep/y", "next_footstep/yaw",
            "dcm_error/x", "dcm_error/y",
            *(f"last_action/{name}" for name in self.layout.entry_names()),
        )

    def action_names(self) -> tuple[str, ...]:
        return self.layout.entry_names()

    # --- episode --------------------------------------------------------------------------
    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        q = self.q0.copy()
        q[7:] += self.np_random.uniform(-self.initial_joint_noise, self.initial_joint_noise, self.robot.dofs)
        return q, np.zeros(len(q) - 1)

    def reset_task(self) -> None:
        self._base = self._observed = None
        self._terminated = None
        self.result = None
        start = self.robot.time()  # 0, or the end of a start-up calibration (an estimator in the loop)
        self.schedule = [(start + t, command) for t, command in self.commands.draw(self.np_random)]
        self._next_command = 0
        self.command = np.zeros(3)
        self.last_action = np.zeros(self.layout.size)
        self.previous_action = np.zeros(self.layout.size)
        self._torque[:] = 0.0
        self._torque_on = False
        q, _ = self.robot.generalized_state()
        self.walker.reset(q)

    def dcm_error(self) -> np.ndarray:
        """The walker's DCM error ``ξ − ξ_ref`` (world xy, m; zero before its first step)."""
        state = self.walker.state
        return state.dcm - state.dcm_ref if self.walker.phase is not Phase.STAND or state.steps else np.zeros(2)

    def gate(self) -> float:
        """How much of the residual acts now (1 without ``residual_gate``)."""
        if self.residual_gate is None:
            return 1.0
        return error_gate(float(np.hypot(*self.dcm_error())), *self.residual_gate)

    def set_action(self, action: np.ndarray) -> None:
        self.previous_action = self.last_action
        self.last_action = np.array(action, dtype=float)
        residuals = self.layout.split(self.last_action)
        walker = self.walker
        if "hip" in residuals:  # a gain: the hip strategy gates its roll itself (module docstring)
            walker.set_hip_residual(float(residuals.pop("hip")[0]))
        gate = self.gate()
        if gate != 1.0:
            residuals = {name: gate * value for name, value in residuals.items()}
        if "torque" in residuals:
            self._torque[self._torque_joints] = residuals["torque"]
            self._torque_on = bool(np.any(residuals["torque"] != 0.0))
        if "step" in residuals:
            step = residuals["step"]
            walker.set_step_residual(step[:2], float(step[2]))
        if "com" in residuals or "orientation" in residuals:
            com = residuals.get("com", np.zeros(3))
            yaw = _yaw(self.observed_base_state().quaternion)
            c, s = math.cos(yaw), math.sin(yaw)
            dcm = np.array([c * com[0] - s * com[1], s * com[0] + c * com[1]])
            walker.set_reference_residual(dcm, float(com[2]), residuals.get("orientation"))

    def apply_command(self) -> None:
        """Switch to the next scheduled command when due, then one walker tick."""
        robot = self.robot
        t = robot.time()
        schedule = self.schedule
        while self._next_command < len(schedule) and schedule[self._next_command][0] <= t + 1e-9:
            self.command = np.array(schedule[self._next_command][1])
            self.walker.set_command(*schedule[self._next_command][1])
            self._next_command += 1
        self.result = self.walker.step(robot)
        if self._torque_on:  # the torque block: the WBC's torques plus the residual (the zero residual sends nothing more)
            robot.set_joint_torques(self.result.tau + self._torque)
        set_plan = getattr(robot, "set_contact_plan", None)
        if set_plan is not None:  # an estimating robot: a swinging foot is never taken as a stance foot
            set_plan(self.walker.single_support_plan(self._plans))

    def is_terminated(self) -> bool:
        """Fallen (base low or tilted), or, with ``joint_limit_margin``, a joint beyond its soft limits."""
        if super().is_terminated():
            return True
        if self.joint_limit_margin is None:
            return False
        now = self.robot.time()
        if self._terminated is None or self._terminated[0] != now:
            q = self.robot.joint_positions()
            self._terminated = (now, bool(np.any(q < self._soft_lower) or np.any(q > self._soft_upper)))
        return self._terminated[1]

    def controller_failure(self) -> str | None:
        return None if self.result is None else self.result.failure()

    # --- outputs --------------------------------------------------------------------------
    def heading_velocity(self, base: BaseState | None = None) -> np.ndarray:
        """Base ``(vx, vy, yaw_rate)`` in the heading frame (yaw of the pelvis): of ``base``, else the true base."""
        base = self.base_state() if base is None else base
        yaw = _yaw(base.quaternion)
        c, s = math.cos(yaw), math.sin(yaw)
        v = base.linear_velocity
        return np.array([c * v[0] + s * v[1], -s * v[0] + c * v[1], base.angular_velocity[2]])

    def get_observation(self) -> np.ndarray:
        robot, walker = self.robot, self.walker
        imu = robot.imu()
        up = quat_to_matrix(imu.quaternion)[2]
        base = self.observed_base_state()
        yaw = _yaw(base.quaternion)
        c, s = math.cos(yaw), math.sin(yaw)
        phase = walker.phase
        step = walker.next_footstep()
        dx, dy = step.position[0] - base.position[0], step.position[1] - base.position[1]
        error = self.dcm_error()
        return np.concatenate([
            -up,
            ANGULAR_VELOCITY_SCALE * imu.angular_velocity,
            robot.joint_positions() - self.default_positions,
            JOINT_VELOCITY_SCALE * robot.joint_velocities(),
            self.heading_velocity(base),
            self.command,
            [float(phase is p) for p in _PHASES],
            [1.0 if walker.state.stance == "left" else -1.0, walker.phase_progress()],
            [c * dx + s * dy, -s * dx + c * dy, math.remainder(step.yaw - yaw, 2 * math.pi)],
            [c * error[0] + s * error[1], -s * error[0] + c * error[1]],
            self.last_action,
        ]).astype(np.float32)

    def get_reward(self) -> float:
        w = self.rewards
        velocity = self.heading_velocity()
        error = velocity[:2] - self.command[:2]
        yaw_error = velocity[2] - self.command[2]
        effort = self.robot.joint_efforts() * self._effort_scale
        change = self.last_action - self.previous_action
        residual = float(self.last_action @ self.last_action) / self.last_action.size if w.action else 0.0
        beyond = 0.0
        if w.joint_limits:
            q = self.truth.joint_positions()
            beyond = float(np.sum(np.maximum(q - self._band_upper, 0.0) + np.maximum(self._band_lower - q, 0.0)))
        return float(
            w.alive
            + w.tracking * math.exp(-float(error @ error) / w.tracking_width**2)
            + w.yaw_tracking * math.exp(-(yaw_error / w.yaw_tracking_width) ** 2)
            + w.upright * math.exp(-((self.tilt() / w.upright_width) ** 2))
            - w.effort * float(effort @ effort) / effort.size
            - w.action_rate * float(change @ change) / change.size
            - w.action * residual
            - w.joint_limits * beyond
            - (w.fall if self.is_terminated() else 0.0)
        )

    def get_info(self) -> dict[str, Any]:
        base = self.base_state()
        state = self.walker.state
        return {
            "base_height": float(base.position[2]),
            "tilt": self.tilt(),
            "base_xy": base.position[:2].copy(),
            "base_yaw": _yaw(base.quaternion),
            "base_velocity_xy": base.linear_velocity[:2].copy(),  # world frame, true: for per-tick tracking
            "base_yaw_rate": float(base.angular_velocity[2]),  # world z, rad/s
            "command": self.command.copy(),
            "phase": self.walker.phase.value,
            "steps": state.steps,
            "recovery_steps": state.recovery_steps,
        }

    def describe(self) -> dict[str, Any]:
        return self.residual_description("walker")


__all__ = ["CommandRanges", "G1Walk", "WalkRewards", "WalkScales"]
