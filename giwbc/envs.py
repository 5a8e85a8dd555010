"""Registered environments: ``gymnasium.make("giwbc/<Id>")`` after ``import giwbc.envs``
(or, with nothing imported, ``gymnasium.make("giwbc.envs:giwbc/<Id>")``).

Each id is a factory building a Task and a :class:`SimulatedRuntime` over a robot description.
Keyword arguments of ``gymnasium.make`` reach the factory: rates, ``real_time_factor``,
``render_mode``, ``sim2real`` (a :class:`SimToReal` or a dict of its fields), and

* ``engine``: ``"mujoco"`` (default), ``"pybullet"``, or a per-episode random choice
  (an :class:`~giwbc.randomization.EngineChoice` or ``{"mujoco": 0.5, "pybullet": 0.5}``);
* ``randomization``: domain randomization applied at every reset: a config dict, a TOML path,
  ``"default"`` (the robot's ``randomization.toml``), a RandomizationConfig or a DomainRandomizer;
* ``engine_options``: constructor keywords per engine (``{"pybullet": {"solver_iterations": 50}}``);
* ``model``: a modified ``mujoco.MjModel`` to simulate instead of the description's (MuJoCo
  only; it is copied);

and the task's own options. Every option is JSON-friendly in its plain form, so a policy's
metadata can carry it.
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING, Any

import gymnasium

if TYPE_CHECKING:
    import mujoco

    from giwbc.robot.description import RobotDescription
    from giwbc.runtimes.simulated import SimulatedRuntime
    from giwbc.tasks.task import Task

NAMESPACE = "giwbc"
CARTPOLE_BALANCE = "giwbc/CartPoleBalance-v0"
CARTPOLE_SWING_UP = "giwbc/CartPoleSwingUp-v0"
G1_BALANCE = "giwbc/G1Balance-v0"
G1_WALK = "giwbc/G1Walk-v0"

# id -> (entry point, max_episode_steps); each entry point is a factory below.
ENVIRONMENTS: dict[str, tuple[str, int]] = {
    CARTPOLE_BALANCE: ("giwbc.envs:cartpole_balance", 500),
    CARTPOLE_SWING_UP: ("giwbc.envs:cartpole_swing_up", 1000),
    G1_BALANCE: ("giwbc.envs:g1_balance", 1000),
    G1_WALK: ("giwbc.envs:g1_walk", 1000),
}


def simulated_env(
    task: "Task",
    description: "str | RobotDescription",
    *,
    model: "mujoco.MjModel | None" = None,
    agent_rate: float,
    controller_rate: float | None = None,
    real_time_factor: float | None = None,
    render_mode: str | None = None,
    sim2real: Any = None,
    render_size: tuple[int, int] = (480, 640),
    engine: Any = None,
    engine_options: dict[str, dict[str, Any]] | None = None,
    randomization: Any = None,
) -> "SimulatedRuntime":
    """A simulated runtime for ``task`` on the robot ``description`` (a name, a path or a description)."""
    from giwbc.robot import RobotDescription, load
    from giwbc.runtimes import SimulatedRuntime

    if not isinstance(description, RobotDescription):
        description = load(description)
    options = {name: dict(values) for name, values in (engine_options or {}).items()}
    if model is not None:
        options.setdefault("mujoco", {})["model"] = copy.copy(model)
    return SimulatedRuntime(
        task,
        description,
        agent_rate=agent_rate,
        controller_rate=controller_rate,
        real_time_factor=real_time_factor,
        render_mode=render_mode,
        sim2real=sim2real,
        render_size=render_size,
        engine=engine,
        engine_options=options,
        randomizer=randomization,
    )


# What gymnasium.make options go to the runtime rather than the task (a deployment drops them too).
RUNTIME_OPTIONS = ("model", "controller_rate", "real_time_factor", "render_mode", "sim2real", "render_size",
                   "engine", "engine_options", "randomization")


def _split(kwargs: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    runtime = {k: kwargs.pop(k) for k in RUNTIME_OPTIONS if k in kwargs}
    return runtime, kwargs


def cartpole_balance(*, robot: "str | RobotDescription" = "cartpole", agent_rate: float = 50.0, **kwargs: Any) -> "SimulatedRuntime":
    """``giwbc/CartPoleBalance-v0``: keep the pole upright (task options: see :class:`CartPoleBalance`)."""
    from giwbc.tasks.cartpole import CartPoleBalance

    runtime, task = _split(kwargs)
    return simulated_env(CartPoleBalance(**task), robot, agent_rate=agent_rate, **runtime)


def cartpole_swing_up(*, robot: "str | RobotDescription" = "cartpole", agent_rate: float = 50.0, **kwargs: Any) -> "SimulatedRuntime":
    """``giwbc/CartPoleSwingUp-v0``: swing the pole up and hold it (see :class:`CartPoleSwingUp`)."""
    from giwbc.tasks.cartpole import CartPoleSwingUp

    runtime, task = _split(kwargs)
    return simulated_env(CartPoleSwingUp(**task), robot, agent_rate=agent_rate, **runtime)


def g1_balance(
    *,
    robot: "str | RobotDescription" = "g1",
    agent_rate: float = 50.0,
    controller_rate: float | None = None,
    sim2real: Any = None,
    **kwargs: Any,
) -> "SimulatedRuntime":
    """``giwbc/G1Balance-v0``: G1 standing under random pushes, residual actions over the WBC.

    The WBC runs at 500 Hz unless ``controller_rate`` says otherwise (the ``controller="pd"``
    baseline at the agent rate: the actuators evaluate its impedance every physics step). Pushes
    are on by default (:class:`PushConfig`) unless the ``randomization`` config draws its own;
    ``sim2real={"pushes": None}`` turns them off.
    """
    from giwbc.randomization import make_randomizer
    from giwbc.robot import RobotDescription, load
    from giwbc.runtimes import PushConfig
    from giwbc.tasks.balance import G1Balance

    description = robot if isinstance(robot, RobotDescription) else load(robot)
    randomizer = make_randomizer(kwargs.pop("randomization", None), description)  # validated once, here
    own_pushes = randomizer is not None and "push_force" in randomizer.config.parameters
    if (sim2real is None or isinstance(sim2real, dict)) and not own_pushes:
        sim2real = {"pushes": PushConfig(), **(sim2real or {})}
    if controller_rate is None:
        controller_rate = 500.0 if kwargs.get("controller", "wbc") == "wbc" else agent_rate
    runtime, task = _split(kwargs)
    return simulated_env(G1Balance(description, **task), description, agent_rate=agent_rate, controller_rate=controller_rate,
                         sim2real=sim2real, randomization=randomizer, **runtime)


def g1_walk(
    *,
    robot: "str | RobotDescription" = "g1",
    agent_rate: float = 50.0,
    controller_rate: float = 500.0,
    sim2real: Any = None,
    **kwargs: Any,
) -> "SimulatedRuntime":
    """``giwbc/G1Walk-v0``: G1 tracking velocity commands, residual actions over the model-based
    walker and its WBC (500 Hz). Pushes only when asked (``sim2real={"pushes": {...}}`` or the
    ``randomization`` config's); task options: see :class:`~giwbc.tasks.walk.G1Walk`."""
    from giwbc.randomization import make_randomizer
    from giwbc.robot import RobotDescription, load
    from giwbc.tasks.walk import G1Walk

    description = robot if isinstance(robot, RobotDescription) else load(robot)
    randomizer = make_randomizer(kwargs.pop("randomization", None), description)
    runtime, task = _split(kwargs)
    return simulated_env(G1Walk(description, **task), description, agent_rate=agent_rate, controller_rate=controller_rate,
                         sim2real=sim2real, randomization=randomizer, **runtime)


def register_envs() -> None:
    """Register every giwbc id with gymnasium (idempotent)."""
    for env_id, (entry_point, max_steps) in ENVIRONMENTS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point, max_episode_steps=max_steps)


register_envs()
