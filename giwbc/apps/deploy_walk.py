"""``giwbc deploy --controller walk``: the walking controller
(:class:`~giwbc.locomotion.walker.WalkingController`) on the deployment path.

It reads what a deployment has: the estimated base and the encoders (``robot.generalized_state()``
of an :class:`~giwbc.estimation.estimated_robot.EstimatedRobot`) and, for early and late
touch-downs, the estimator's ground force on each sole (``robot.contact_wrench``: estimated from
the leg's joint efforts, or a foot sensor's). It stands for ``walk_delay`` seconds after the
start-up ramp (the WBC takes the robot over from the ramp's joint PD and the estimate settles),
then walks at the command; it outputs the WBC's impedance command (feed-forward torque, low gains)
as :class:`giwbc.apps.deploy_setup.WbcHold` does.

``giwbc deploy --policy g1_walk_residual.onnx`` (task ``walk``): :class:`WalkPolicyTask`, the
policy's :class:`~giwbc.tasks.walk.G1Walk` task (its residual blocks and scales from the ONNX
metadata) whose walker is driven as :class:`WalkHold` drives it (the deployment walker
configuration, estimated foot forces, the schedule's contacts to the estimator, the impedance
output, the command after ``walk_delay``); the policy sets its residuals at its agent rate.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from giwbc.apps.arguments import number, seconds
from giwbc.errors import DeployError
from giwbc.estimation.estimated_robot import EstimatedRobot
from giwbc.locomotion.walker import Phase, WalkerConfig, WalkingController
from giwbc.locomotion.walker_config import DEPLOYMENT_OPTIONS, walker_config
from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import ImpedanceCommand, Robot
from giwbc.tasks.walk import G1Walk


@dataclass(frozen=True)
class WalkCommand:
    """The velocity command of a deployed walk (body frame), and when it starts."""

    vx: float = 0.0  # m/s
    vy: float = 0.0  # m/s
    yaw_rate: float = 0.0  # rad/s
    step_in_place: bool = False
    walk_delay: float = 0.5  # s after the controller's first tick (standing until then)

    def __post_init__(self) -> None:
        values = (self.vx, self.vy, self.yaw_rate, self.walk_delay)
        if not all(math.isfinite(v) for v in values):
            raise DeployError(f"walk command must be finite, got vx={self.vx}, vy={self.vy}, yaw_rate={self.yaw_rate}, delay={self.walk_delay}")
        if self.walk_delay < 0:
            raise DeployError(f"walk_delay must be >= 0, got {self.walk_delay}")

    @property
    def moves(self) -> bool:
        return self.step_in_place or any(v != 0.0 for v in (self.vx, self.vy, self.yaw_rate))


# The deployment walker's options (giwbc.locomotion.walker_config.DEPLOYMENT_OPTIONS, why each there).
DEPLOY_WALKER_OPTIONS: Mapping[str, Any] = DEPLOYMENT_OPTIONS
DEPLOY_MAX_ADJUSTMENT = float(DEPLOYMENT_OPTIONS["max_adjustment"])


def deploy_walker_config() -> WalkerConfig:
    """The walker's configuration on the deployment path (estimated base and foot forces): online
    step adjustment on the shaped estimated DCM error, a later touch-down threshold and a softer
    swing foot (:data:`~giwbc.locomotion.walker_config.DEPLOYMENT_OPTIONS`, why each there)."""
    return walker_config("deployment")


class WalkHold:
    """The walking controller as a deployment controller: called with the robot each control
    tick, returns the joint impedance command (see the module docstring)."""

    def __init__(
        self, description: RobotDescription, command: WalkCommand | None = None, config: WalkerConfig | None = None, *, foot_forces: bool = True,
        contact_plan: bool = True, max_failed_ticks: int = 5, walker: WalkingController | None = None,
    ) -> None:
        """``walker``: drive this walker (a task's) instead of building one from ``config``."""
        self.walker = walker or WalkingController(description, config or deploy_walker_config())
        self.foot_forces = foot_forces  # False: touch-downs on the schedule alone
        self.contact_plan = contact_plan  # pass the schedule's contacts to an estimating robot
        self.command = command or WalkCommand()
        self._links = {side: contact.link for side, contact in self.walker.contacts.items()}
        order = [c.link for c in description.contacts]  # the estimator's contact order
        self._index = {side: order.index(link) for side, link in self._links.items()}
        self._plans = self.walker.contact_plans(order)
        self._anchor = True
        self._started_at: float | None = None
        self._commanded = False
        self.max_failed_ticks = max_failed_ticks
        self.notes: list[str] = []
        self.last: Any = None
        self.single_support_ticks = 0  # ticks in single support (a foot swinging): the contact switches seen

    def reset(self) -> None:
        """Stand again, re-anchored at the next tick's measured state; the command starts again
        ``walk_delay`` after it."""
        self._anchor = True
        self._commanded = False

    def __call__(self, robot: Robot) -> ImpedanceCommand:
        q, v = robot.generalized_state()
        now = robot.time()
        walker = self.walker
        if self._anchor:
            walker.reset(q)
            self._anchor, self._started_at = False, now
        if not self._commanded and self.command.moves and now - self._started_at >= self.command.walk_delay - 1e-9:
            c = self.command
            self.notes.extend(walker.set_command(c.vx, c.vy, c.yaw_rate, step_in_place=c.step_in_place))
            self._commanded = True
        forces = self._foot_forces(robot) if self.foot_forces else None
        self.last = walker.update(q, v, now, forces)
        single = walker.state.phase is Phase.SINGLE
        self.single_support_ticks += single
        set_plan = getattr(robot, "set_contact_plan", None)
        if self.contact_plan and set_plan is not None:
            set_plan(walker.single_support_plan(self._plans))  # the schedule's contacts while a foot swings
        return self.last.impedance

    def _foot_forces(self, robot: Robot) -> dict[str, float]:
        """Normal ground force per sole (N): the estimate's own array on an estimating robot (its
        ``contact_wrench`` would also compute the link poses, ~2 forward kinematics a tick)."""
        if isinstance(robot, EstimatedRobot):
            forces = robot.estimate.contact_forces
            return {side: float(forces[i, 2]) for side, i in self._index.items()}
        return {side: float(robot.contact_wrench(link).force[2]) for side, link in self._links.items()}

    @property
    def steps(self) -> int:
        """Touch-downs so far."""
        return self.walker.state.steps

    @property
    def active_command(self) -> np.ndarray:
        """``(vx, vy, yaw_rate)`` the walker is walking at: zeros until the command started."""
        c = self.command
        return np.array([c.vx, c.vy, c.yaw_rate]) if self._commanded else np.zeros(3)

    def failure(self) -> str | None:
        """Why the controller fell back to its safe command for ``max_failed_ticks`` ticks in a row,
        or None (the runtime stops on it). A single infeasible tick at a contact switch is ridden
        out on the decaying last torques, as in simulation."""
        last = self.last
        if last is None or last.ok or self.walker.wbc.consecutive_failures < self.max_failed_ticks:
            return None
        return f"{self.walker.wbc.consecutive_failures} ticks in a row: walking {last.failure()}"


class WalkPolicyTask(G1Walk):
    """A walking policy's task on the deployment path: :class:`~giwbc.tasks.walk.G1Walk` (the
    policy's observation, its residual blocks on the walker) with the walker driven by a
    :class:`WalkHold` (module docstring) at the deploy command instead of the training's random
    command schedule. ``task_kwargs``: the policy's env_kwargs for the task."""

    def __init__(self, description: RobotDescription, command: WalkCommand | None = None, **task_kwargs: Any) -> None:
        trained = task_kwargs.pop("walker", None)
        if trained == "deployment":  # trained on the deployment walker: the same walker, as trained
            walker: dict[str, Any] | str = "deployment"
        else:
            # A policy trained on the simulation walker, without online step adjustment: its residual
            # already moves the steps, and the shipped (barely trained) policy plus the shaped
            # adjustment on the estimate put the emulated G1's ankle roll on its soft limit within 2
            # steps; without it, 20 s walked.
            walker = {**dict(trained or {}), **DEPLOY_WALKER_OPTIONS, "step_adaptation": False}
        super().__init__(description, walker=walker, **task_kwargs)
        self.hold = WalkHold(description, command, walker=self.walker)

    def reset_task(self) -> None:
        super().reset_task()
        self.hold.reset()

    def apply_command(self) -> None:
        """One walker tick on the estimated state; the command observed is the one walked at."""
        robot = self.robot
        impedance = self.hold(robot)
        self.result = self.hold.last
        self.command = self.hold.active_command
        if self._torque_on:  # the policy's torque block: on the feed-forward torque, as the simulation adds it to the WBC's
            impedance = replace(impedance, tau_ff=np.asarray(impedance.tau_ff, dtype=float) + self._torque)
        robot.set_joint_impedance(impedance)

    def controller_failure(self) -> str | None:
        return self.hold.failure()


MAX_VX, MAX_VY, MAX_YAW_RATE = 1.5, 1.0, 2.0  # m/s, m/s, rad/s: the commands the command line takes (the walker clamps to its gait)


def add_walk_arguments(parser: argparse.ArgumentParser) -> None:
    """``giwbc deploy``'s walking options (numbers checked by their argparse types)."""
    parser.add_argument("--vx", type=number(-MAX_VX, MAX_VX, unit="m/s"), default=0.0,
                        help=f"with --controller walk or a walking policy: forward speed, m/s (body frame), |vx| <= {MAX_VX:g}")
    parser.add_argument("--vy", type=number(-MAX_VY, MAX_VY, unit="m/s"), default=0.0,
                        help=f"with --controller walk or a walking policy: lateral speed, m/s, |vy| <= {MAX_VY:g}")
    parser.add_argument("--yaw-rate", type=number(-MAX_YAW_RATE, MAX_YAW_RATE, unit="rad/s"), default=0.0,
                        help=f"with --controller walk or a walking policy: turning rate, rad/s, |yaw rate| <= {MAX_YAW_RATE:g}")
    parser.add_argument("--step-in-place", action="store_true", help="with --controller walk or a walking policy: step with a zero command")
    parser.add_argument("--walk-delay", type=seconds(60.0, allow_zero=True), default=WalkCommand.walk_delay,
                        help="with --controller walk or a walking policy: s of standing after the start-up ramp before the command")
    parser.add_argument("--walker", default=None, metavar="JSON",
                        help="with --controller walk: WalkerConfig fields over the deployment walker's, e.g. "
                             "'{\"adapt_full_error\": 0.06, \"adapt_freeze_time\": 0.1}' (the lateral-push options, README); "
                             "every number finite; a walking policy runs on the walker it was trained on")


def walk_command(args: argparse.Namespace) -> WalkCommand | None:
    """The walk command of parsed ``giwbc deploy`` arguments: None when no walking option was given
    and the controller is not ``walk`` (whether the task walks is known once the policy is loaded:
    :func:`giwbc.apps.deploy_setup.choose_task` refuses a command for a task that does not walk);
    :class:`DeployError` for a non-finite one."""
    given = bool(args.vx or args.vy or args.yaw_rate or args.step_in_place or args.walk_delay != WalkCommand.walk_delay)
    if args.controller != "walk" and not given:
        return None
    return WalkCommand(args.vx, args.vy, args.yaw_rate, args.step_in_place, args.walk_delay)


def walker_overrides(args: argparse.Namespace) -> dict[str, Any] | None:
    """``--walker``'s WalkerConfig fields (None when not given), checked by building the walker's
    configuration from them: :class:`DeployError` names what is wrong (not JSON, not an object,
    an unknown field, a value the walker refuses) before anything starts."""
    text = getattr(args, "walker", None)
    if text is None:
        return None
    try:
        overrides = json.loads(text)
    except json.JSONDecodeError as error:
        raise DeployError(f"--walker must be a JSON object of WalkerConfig fields: {error}") from None
    if not isinstance(overrides, dict):
        raise DeployError(f"--walker must be a JSON object of WalkerConfig fields, got {text!r}")
    for key, value in overrides.items():
        bad = non_finite(value)
        if bad is not None:
            raise DeployError(f"--walker: {key} must be finite numbers, got {bad}")
    try:
        walker_config(overrides, base=deploy_walker_config())
    except (TypeError, ValueError) as error:
        raise DeployError(f"--walker: {error}") from None
    return overrides


def non_finite(value: Any) -> str | None:
    """The first number in a JSON value that is not finite (JSON's NaN, Infinity, or a float
    overflowing to inf like 1e999), as text, or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    if isinstance(value, list):
        return next((bad for bad in map(non_finite, value) if bad is not None), None)
    if isinstance(value, dict):
        return next((bad for bad in map(non_finite, value.values()) if bad is not None), None)
    return None


__all__ = ["DEPLOY_WALKER_OPTIONS", "WalkCommand", "WalkHold", "WalkPolicyTask", "add_walk_arguments", "non_finite", "walk_command", "walker_overrides"]
