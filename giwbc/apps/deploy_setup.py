"""Which task and controller ``giwbc deploy`` runs, built from ``--task``, ``--controller``,
``--policy`` and the walking options, and the refusals of combinations that cannot run.

Tasks (:data:`TASKS`): ``stand`` (no policy: a controller of :data:`CONTROLLERS` holds the robot,
:func:`make_controller`), ``balance`` (a balance policy's :class:`~giwbc.tasks.balance.G1Balance`)
and ``walk`` (a walking policy, metadata ``env_id`` :data:`WALK_ENV`:
:class:`~giwbc.apps.deploy_walk.WalkPolicyTask`); with a policy the default is its own. A
policy's metadata is checked against the robot and the rates (:func:`check_policy_metadata`, a
plain-dict check) and its observation and action layout against the task (:func:`check_layout`).
Refused (:func:`choose_task`): a policy on ``stand``; the ``walk`` task without a walking policy;
a walking policy with ``--task balance`` or ``--controller pd``, a balance policy with ``--task
walk``; the walk controller with a policy that does not walk; walking options for a task that does
not walk; and the walking policy without the state estimator (or without a floating base).

A first run (``--first-run``: the robot hangs on a gantry, feet clear) runs the joint-PD hold
(``--controller pd``, its default): the WBC, the walker and every policy balance on the feet's
ground forces, and the state estimator's start-up calibration waits for both feet to carry the
robot, which on a gantry never happens (it used to stop after the 15 s calibration timeout, with
the motors on). Any of them with ``--first-run`` is refused before anything starts.
"""

from __future__ import annotations

import inspect
import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from giwbc.apps.deploy_options import CONTROLLERS, FIRST_RUN_CONTROLLER, TASKS, DeployOptions
from giwbc.apps.deploy_walk import WalkCommand, WalkHold, WalkPolicyTask, deploy_walker_config
from giwbc.control.balance import make_balance_controller
from giwbc.envs import RUNTIME_OPTIONS
from giwbc.errors import DeployError
from giwbc.locomotion.walker_config import walker_config
from giwbc.policy import OnnxPolicy, PolicyFormatError
from giwbc.util.shipped import policy_by_name
from giwbc.robot.description import RobotDescription
from giwbc.robot.standing import PdHold
from giwbc.tasks.balance import G1Balance
from giwbc.tasks.standing import StandingTask

WALK_ENV = "giwbc/G1Walk-v0"  # a walking policy's env_id: the deploy task "walk"


def _runtime_keys() -> frozenset[str]:
    """Env kwargs that configure the simulated runtime or ``gymnasium.make``'s wrappers
    (``max_episode_steps``, ...), not the task: the deployment drops them."""
    named = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    make_options = {name for name, p in inspect.signature(gymnasium.make).parameters.items() if p.kind in named} - {"id"}
    return frozenset({"robot", "agent_rate", *RUNTIME_OPTIONS, *make_options})


# ----------------------------------------------------------------------------- policy metadata
def check_policy_metadata(metadata: Mapping[str, Any], description: RobotDescription, control_rate: float) -> float:
    """Check a policy's metadata (a plain dict, as exported with the policy) against the robot and
    the control rate; returns the policy's agent rate. Raises :class:`DeployError` listing every
    mismatch: joint names or order, controller rate, agent rate not dividing it, action and
    observation names missing."""
    problems: list[str] = []
    joints = list(metadata.get("joint_names") or [])
    if joints != list(description.joint_names):
        if sorted(joints) == sorted(description.joint_names):
            problems.append("joint order differs from the robot's (same names): the policy's arrays would be permuted")
        else:
            missing = [j for j in description.joint_names if j not in joints]
            extra = [j for j in joints if j not in description.joint_names]
            problems.append(f"joint names differ from the robot's: missing {missing}, unknown {extra}")
    rates = metadata.get("rates")
    agent = math.nan
    if not isinstance(rates, Mapping):
        problems.append("no rates in the metadata (agent_hz, controller_hz)")
    else:
        agent = float(rates.get("agent_hz", math.nan))
        controller = float(rates.get("controller_hz", math.nan))
        if not math.isclose(controller, control_rate, rel_tol=1e-9):
            problems.append(f"trained with the controller at {controller:g} Hz, deploying at {control_rate:g} Hz")
        if not (agent > 0 and abs(control_rate / agent - round(control_rate / agent)) < 1e-9):
            problems.append(f"agent rate {agent:g} Hz does not divide the control rate {control_rate:g} Hz")
    for key in ("action_names", "observation_names"):
        if not metadata.get(key):
            problems.append(f"no {key} in the metadata")
    if problems:
        raise DeployError("policy does not match the robot: " + "; ".join(problems))
    return agent


def load_policy(path: str | Path) -> tuple[Callable[[np.ndarray], np.ndarray], dict[str, Any]]:
    """A policy callable and its metadata: an exported ``.onnx`` (:class:`giwbc.policy.OnnxPolicy`)
    or a ``.json`` holding metadata only (a rehearsal with zero actions); a shipped policy by name
    (``g1_walk_residual``, or ``policies/g1_walk_residual.onnx`` where no such file exists)."""
    path = policy_by_name(str(path)) or Path(path)
    if not path.is_file():
        raise DeployError(f"no policy file at {path}")
    if path.suffix == ".json":
        metadata = json.loads(path.read_text())
        size = len(metadata.get("action_names") or [])
        return (lambda observation: np.zeros(size, dtype=np.float32)), metadata
    try:
        policy = OnnxPolicy(path)
    except (PolicyFormatError, ImportError) as error:
        raise DeployError(f"cannot load the policy: {error}") from error
    return policy, dict(policy.metadata)


# ----------------------------------------------------------------------------- controllers
class WbcHold:
    """The QP standing balance controller (:mod:`giwbc.control.balance`): its impedance output
    (feed-forward torque plus joint damping) from the estimated Pinocchio state."""

    def __init__(self, description: RobotDescription, **options: Any) -> None:
        self.balance = make_balance_controller(description, **options)
        self._anchor = True
        self.last: Any = None

    def reset(self) -> None:
        """Re-anchor the references (CoM, heading) at the next tick's measured state."""
        self._anchor = True

    def __call__(self, robot: Any) -> Any:
        q, v = robot.generalized_state()
        if self._anchor:
            self.balance.reset(q)
            self._anchor = False
        self.last = self.balance.update(q, v, robot.time())
        return self.last.impedance

    def failure(self) -> str | None:
        """Why the last tick fell back to its safe command (infeasible QP, unusable state), or None:
        the runtime stops on it (a fault), instead of running on a decaying fallback."""
        return None if self.last is None else self.last.failure()


def make_controller(name: str, description: RobotDescription, walk: WalkCommand | None = None, walker: Mapping[str, Any] | None = None) -> Any:
    """A deployment controller by name; ``walk``: the ``walk`` controller's command (default:
    stand); ``walker``: its WalkerConfig fields over the deployment walker's."""
    if name == "walk":
        return WalkHold(description, walk, walker_config(walker, base=deploy_walker_config()) if walker else None)
    if name == "pd":
        return PdHold(description)
    if name == "wbc":
        return WbcHold(description)
    raise DeployError(f"unknown controller {name!r}; choose from {', '.join(CONTROLLERS)}")



# ----------------------------------------------------------------------------- the task
def choose_task(options: DeployOptions, metadata: Mapping[str, Any] | None, policy: Any, description: RobotDescription) -> str:
    """The task to run (see :class:`~giwbc.apps.deploy_options.DeployOptions`); :class:`DeployError` for combinations that
    cannot run (module docstring)."""
    _check_first_run(options, metadata is not None or policy is not None)
    env_id = str((metadata or {}).get("env_id") or "").split(":", 1)[-1]
    walking_policy = env_id == WALK_ENV
    if options.task is not None:
        task_name = options.task
    elif metadata is not None:
        task_name = "walk" if walking_policy else "balance"
    else:
        task_name = "stand"
    if task_name not in TASKS:
        raise DeployError(f"unknown task {task_name!r}; choose from {', '.join(TASKS)}")
    if task_name == "stand" and policy is not None:
        raise DeployError("the 'stand' task takes no action: a policy needs --task balance or walk")
    if task_name == "walk":
        if metadata is None:
            raise DeployError(f"the 'walk' task runs a walking policy ({WALK_ENV}): give --policy (or walk without one: --controller walk)")
        if not walking_policy:
            raise DeployError(f"the 'walk' task needs a {WALK_ENV} policy; this one is for {env_id or 'an unnamed env'}")
        if options.controller == "pd":
            raise DeployError("the walking policy runs over the walker and its WBC: --controller pd cannot run it (use walk, or leave the default)")
    elif options.controller == "walk" and task_name != "stand":
        raise DeployError("the walk controller runs the 'stand' task (no policy) or a walking policy (task 'walk')")
    elif walking_policy and task_name == "balance":
        raise DeployError(f"this policy is for {WALK_ENV}: run it with --task walk (the default for it)")
    if options.walker and not (task_name == "stand" and options.controller == "walk"):
        raise DeployError("--walker configures the walk controller (--controller walk, no policy): a walking policy runs on the walker it was trained on")
    if options.walk is not None and options.walk.moves and task_name != "walk" and options.controller != "walk":
        raise DeployError("--vx/--vy/--yaw-rate/--step-in-place need --controller walk or a walking policy")
    if task_name == "walk" and (options.estimator is False or not description.floating_base):
        raise DeployError("the walking policy walks on the state estimator's base state: it needs a floating base and the estimator")
    return task_name



def _check_first_run(options: DeployOptions, has_policy: bool) -> None:
    """On a gantry (``first_run``) only the joint-level hold runs (module docstring)."""
    if not options.first_run:
        return
    fix = f"on a gantry run the joint PD hold: --controller {FIRST_RUN_CONTROLLER} (the default with --first-run)"
    if has_policy:
        raise DeployError(f"--first-run (robot on a gantry, feet clear): a policy balances on the feet, which carry nothing there; {fix}")
    if options.controller != FIRST_RUN_CONTROLLER:
        raise DeployError(f"--first-run (robot on a gantry, feet clear): --controller {options.controller} balances on the feet's ground "
                          f"forces and waits for them to carry the robot before it starts; {fix}")  # fmt: skip
    if options.estimator:
        raise DeployError("--first-run (robot on a gantry, feet clear): the state estimator calibrates standing on both feet; "
                          "leave it off on a gantry (estimator=None or False)")  # fmt: skip


def wants_estimator(options: DeployOptions, task_name: str) -> bool:
    """Whether the controller needs the state estimator's base state: ``options.estimator`` when
    given, else all but the joint-PD hold of the ``stand`` task."""
    return options.estimator if options.estimator is not None else not (task_name == "stand" and options.controller == "pd")


def build_task(task_name: str, description: RobotDescription, metadata: Mapping[str, Any] | None, options: DeployOptions) -> Any:
    """The task :func:`choose_task` chose: the ``stand`` task's controller, or the policy's task."""
    if task_name == "stand":
        return StandingTask(make_controller(options.controller, description, options.walk, options.walker), description.default_positions)
    if task_name == "walk":
        return _walk_task(description, metadata, options.walk)
    return _balance_task(description, metadata, options.controller)


def walking_hold(task: Any) -> WalkHold | None:
    """The walking controller a task drives (the walk controller's, or a walking policy's walker), or None."""
    hold = task.hold if isinstance(task, WalkPolicyTask) else task.controller if isinstance(task, StandingTask) else None
    return hold if isinstance(hold, WalkHold) else None


def _task_kwargs(metadata: Mapping[str, Any] | None) -> dict[str, Any]:
    """The policy's env_kwargs that configure its task (the simulated runtime's are dropped)."""
    return {k: v for k, v in dict((metadata or {}).get("env_kwargs") or {}).items() if k not in _runtime_keys()}


def _walk_task(description: RobotDescription, metadata: Mapping[str, Any] | None, walk: WalkCommand | None) -> WalkPolicyTask:
    try:
        return WalkPolicyTask(description, walk, **_task_kwargs(metadata))
    except (TypeError, ValueError) as error:
        raise DeployError(f"cannot build the walking policy's task: {error}") from error


def _balance_task(description: RobotDescription, metadata: Mapping[str, Any] | None, controller: str) -> Any:
    kwargs = _task_kwargs(metadata)
    kwargs.setdefault("controller", controller)
    try:
        return G1Balance(description, **kwargs)
    except (TypeError, ValueError) as error:
        raise DeployError(f"cannot build the policy's task: {error}") from error


def check_layout(metadata: Mapping[str, Any], task: Any) -> None:
    """The policy's observation and action names are the task's, in order; :class:`DeployError` otherwise."""
    for key, names in (("observation_names", task.observation_names()), ("action_names", task.action_names())):
        if list(metadata.get(key) or []) != list(names):
            raise DeployError(f"the policy's {key} differ from the task's ({len(metadata.get(key) or [])} vs {len(names)} entries)")



__all__ = [
    "CONTROLLERS", "TASKS", "WALK_ENV", "WbcHold", "build_task", "check_layout", "check_policy_metadata", "choose_task", "load_policy",
    "make_controller", "walking_hold", "wants_estimator",
]  # fmt: skip
