"""The factories behind the registered ids (:mod:`giwbc.envs`): each builds a Task and a
:class:`~giwbc.runtimes.simulated.SimulatedRuntime` over a robot description. gymnasium imports
this module on the first ``gymnasium.make`` of a giwbc id (``import giwbc`` stays light)."""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING, Any

from giwbc.envs import RUNTIME_OPTIONS
from giwbc.errors import PlantMismatchError
from giwbc.envs.plant_runtime import PlantDistributionRuntime, is_distribution
from giwbc.plants import resolve_plant
from giwbc.randomization.plant_distribution import PlantDistribution
from giwbc.randomization import make_randomizer
from giwbc.robot import RobotDescription, load
from giwbc.runtimes import PushConfig, SimulatedRuntime
from giwbc.tasks.balance import G1Balance
from giwbc.tasks.walk import G1Walk
from giwbc.tasks.cartpole import CartPoleBalance, CartPoleSwingUp
from giwbc.tasks.task import Task

if TYPE_CHECKING:
    import mujoco


def simulated_env(
    task: Task,
    description: str | RobotDescription,
    *,
    model: mujoco.MjModel | None = None,
    plant: Any = None,
    agent_rate: float,
    controller_rate: float | None = None,
    real_time_factor: float | None = None,
    render_mode: str | None = None,
    sim2real: Any = None,
    render_size: tuple[int, int] = (480, 640),
    engine: Any = None,
    engine_options: dict[str, dict[str, Any]] | None = None,
    randomization: Any = None,
    plant_redraws: int = 0,
) -> SimulatedRuntime:
    """A simulated runtime for ``task`` on the robot ``description`` (a name, a path or a description).

    ``plant``: the MuJoCo plant to simulate instead of the description's own model (a shipped variant's
    name, a variant ``.toml``, an MJCF file, an ``MjModel``: :func:`giwbc.plants.resolve_plant`), bound by
    name and checked against the description; ``model=`` (an ``MjModel``) is the same as ``plant=model``;
    ``"random"``, a plant-distribution dict or TOML, or a PlantDistribution: a plant drawn per episode
    (:class:`~giwbc.envs.plant_runtime.PlantDistributionRuntime`; ``plant_redraws``: its redraws when an
    estimator in the loop cannot calibrate on the drawn plant)."""
    if not isinstance(description, RobotDescription):
        description = load(description)
    options = {name: dict(values) for name, values in (engine_options or {}).items()}
    if model is not None and plant is not None:
        raise PlantMismatchError("give the plant once: model= or plant=, not both")
    if plant_redraws and not is_distribution(plant):
        raise PlantMismatchError("plant_redraws is for a plant drawn per episode (plant='random' or a distribution)")
    if is_distribution(plant):  # a plant drawn per episode (giwbc.envs.plant_runtime)
        return PlantDistributionRuntime(task, description, PlantDistribution.load(plant, description), agent_rate=agent_rate,
                                        controller_rate=controller_rate, real_time_factor=real_time_factor, render_mode=render_mode,
                                        sim2real=sim2real, render_size=render_size, engine=engine, engine_options=engine_options,
                                        randomizer=randomization, plant_redraws=plant_redraws)
    if model is not None:
        options.setdefault("mujoco", {})["model"] = copy.copy(model)
    elif plant is not None:
        options.setdefault("mujoco", {}).update(resolve_plant(description, plant).robot_options())
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


def _split(kwargs: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    runtime = {k: kwargs.pop(k) for k in RUNTIME_OPTIONS if k in kwargs}
    return runtime, kwargs


def cartpole_balance(*, robot: str | RobotDescription = "cartpole", agent_rate: float = 50.0, **kwargs: Any) -> SimulatedRuntime:
    """``giwbc/CartPoleBalance-v0``: keep the pole upright (task options: see :class:`CartPoleBalance`)."""
    runtime, task = _split(kwargs)
    return simulated_env(CartPoleBalance(**task), robot, agent_rate=agent_rate, **runtime)


def cartpole_swing_up(*, robot: str | RobotDescription = "cartpole", agent_rate: float = 50.0, **kwargs: Any) -> SimulatedRuntime:
    """``giwbc/CartPoleSwingUp-v0``: swing the pole up and hold it (see :class:`CartPoleSwingUp`)."""
    runtime, task = _split(kwargs)
    return simulated_env(CartPoleSwingUp(**task), robot, agent_rate=agent_rate, **runtime)


def g1_balance(
    *,
    robot: str | RobotDescription = "g1",
    agent_rate: float = 50.0,
    controller_rate: float | None = None,
    sim2real: Any = None,
    **kwargs: Any,
) -> SimulatedRuntime:
    """``giwbc/G1Balance-v0``: G1 standing under random pushes, residual actions over the WBC.

    The WBC runs at 500 Hz unless ``controller_rate`` says otherwise (the ``controller="pd"``
    baseline at the agent rate: the actuators evaluate its impedance every physics step). Pushes
    are on by default (:class:`PushConfig`) unless the ``randomization`` config draws its own;
    ``sim2real={"pushes": None}`` turns them off.
    """
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
    robot: str | RobotDescription = "g1",
    agent_rate: float = 50.0,
    controller_rate: float = 500.0,
    sim2real: Any = None,
    **kwargs: Any,
) -> SimulatedRuntime:
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


__all__ = ["cartpole_balance", "cartpole_swing_up", "g1_balance", "g1_walk", "simulated_env"]
