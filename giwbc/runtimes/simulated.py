"""The simulated runtime: a ``gymnasium.Env`` running a Task on a simulated robot (MuJoCo or PyBullet).

One agent step, as in Gym-Ignition, with ``n = physics / agent`` physics steps::

    task.set_action(action)              # after `action_latency` physics steps
    for each physics step:
        if controller tick: task.apply_command()   # e.g. the WBC from the task's references
        robot.step()
    observation (+ noise), reward, terminated, truncated, info

At reset, before the task picks its initial state: the episode's engine is drawn (when an
:class:`~giwbc.randomization.EngineChoice` is given), then the domain randomizer samples and
applies its parameters (the engine's model in place, robot-level perturbations in a
:class:`~giwbc.randomization.PerturbedRobot`), all from the seeded ``np_random``.

Physics runs in chunks between events (controller ticks, delayed actions; the perturbed robot
splits further at delayed commands and pushes), so a task without a fast controller costs one
engine call per agent step. The runtime is accelerated by default, or paced to
``real_time_factor``; headless unless a render mode is set (rendering needs MuJoCo).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import gymnasium
import numpy as np

from giwbc.randomization import DomainRandomizer, PerturbedRobot, Randomization, RandomizationError, make_randomizer
from giwbc.randomization.randomizer import RandomizerSpec
from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import Robot
from giwbc.runtimes.engines import EnginePool, EngineSpec
from giwbc.runtimes.estimated import calibrate
from giwbc.tasks.rates import Rates
from giwbc.runtimes.rendering import offscreen_renderer, require_display
from giwbc.runtimes.sim2real import ActionQueue, SimToReal

if TYPE_CHECKING:
    import mujoco

    from giwbc.tasks.task import Task

RENDER_MODES = ("human", "rgb_array")


@runtime_checkable
class SimulatedRobot(Protocol):  # pragma: no mutate block (mutmut would add members to the protocol)
    """What the runtime needs beyond the Robot interface: a simulator's step, reset and push."""

    def step(self, n: int = 1) -> None: ...

    def reset(self, q: np.ndarray | None = None, v: np.ndarray | None = None) -> None: ...

    def set_external_wrench(self, link: str, force: np.ndarray, torque: np.ndarray | None = None) -> None: ...


@dataclass
class StepTimings:
    """Wall time spent inside the runtime since the last :meth:`clear`, by part."""

    physics: float = 0.0
    controller: float = 0.0
    total: float = 0.0
    agent_steps: int = 0
    physics_steps: int = 0

    def clear(self) -> None:
        self.physics = self.controller = self.total = 0.0
        self.agent_steps = self.physics_steps = 0

    @property
    def other(self) -> float:
        return max(0.0, self.total - self.physics - self.controller)


class SimulatedRuntime(gymnasium.Env[np.ndarray, np.ndarray]):
    """Runs ``task`` on a simulated robot at the given agent and controller rates.

    ``robot``: a simulated Robot (the runtime runs on it alone), or a RobotDescription, from which
    the runtime builds a robot per ``engine`` on first use: ``"mujoco"`` (default), ``"pybullet"``,
    or an :class:`~giwbc.randomization.EngineChoice` (or ``{engine: probability}``) drawn at every
    reset; ``engine_options`` are constructor keywords per engine (``{"mujoco": {"model": m}}``).
    ``randomizer``: a DomainRandomizer, a RandomizationConfig, a config dict, a TOML path or
    ``"default"`` (the robot's shipped ``randomization.toml``), applied at every reset.

    The physics rate is the robot's (the description's timestep). ``real_time_factor=None`` runs as
    fast as possible; a number paces simulated time to wall time times that factor. Every random draw
    (the engine, the randomization, the task's initial state, observation noise) comes from the
    seeded ``np_random``, so the same seed gives bit-identical episodes.

    ``render_mode``: ``"rgb_array"`` (offscreen frames, EGL or OSMesa) or ``"human"`` (MuJoCo's
    viewer, paced to real time unless ``real_time_factor`` says otherwise), MuJoCo only; ``"human"``
    where no window can open (no display) is a RenderingUnavailableError here, at construction.
    """

    metadata: dict[str, Any] = {"render_modes": list(RENDER_MODES), "render_fps": 50}

    def __init__(
        self,
        task: Task,
        robot: Robot | RobotDescription,
        *,
        agent_rate: float,
        controller_rate: float | None = None,
        real_time_factor: float | None = None,
        render_mode: str | None = None,
        sim2real: SimToReal | dict[str, Any] | None = None,
        render_size: tuple[int, int] = (480, 640),
        engine: EngineSpec | None = None,
        engine_options: dict[str, dict[str, Any]] | None = None,
        randomizer: RandomizerSpec = None,
    ) -> None:
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {RENDER_MODES} or None, got {render_mode!r}")
        if render_mode == "human":
            require_display()  # refused here: MuJoCo's viewer would end the process where no window can open
        if real_time_factor is not None and not (real_time_factor > 0 and math.isfinite(real_time_factor)):
            raise ValueError(f"real_time_factor must be a positive number or None, got {real_time_factor!r}")
        given = None if isinstance(robot, RobotDescription) else robot
        if given is not None and not isinstance(given, SimulatedRobot):
            raise TypeError(f"{type(robot).__name__} cannot be simulated: it needs step(), reset() and set_external_wrench()")
        description = robot if given is None else getattr(given, "description", None)
        self.sim2real = SimToReal.from_dict(sim2real) if isinstance(sim2real, dict) else sim2real or SimToReal()
        self.randomizer = _randomizer(randomizer, self.sim2real, description)
        self.engines = EnginePool(description, engine, options=engine_options, robot=given, perturbed=self.randomizer is not None)
        if render_mode is not None and set(self.engines.engines) != {"mujoco"}:
            raise ValueError(f"rendering needs the MuJoCo engine; this runtime runs on {list(self.engines.engines)}")
        self.engine = self.engines.engines[0]
        self.sim_robot = self.engines.robot(self.engine)  # the robot the task commands (perturbed or not)
        self.engine_robot = self.engines.engine_robot(self.engine)  # the bare engine robot (ground truth)
        self.randomization: Randomization | None = None  # what the last reset drew
        self.rates = Rates.from_timestep(_timestep(self.sim_robot), agent_rate, controller_rate)
        self.task = task
        self.render_mode = render_mode
        self.real_time_factor = 1.0 if real_time_factor is None and render_mode == "human" else real_time_factor
        self.render_size = render_size
        renders = set(self.engines.engines) == {"mujoco"}  # the modes this instance can render: none off MuJoCo
        self.metadata = {**type(self).metadata, "render_modes": list(RENDER_MODES) if renders else [], "render_fps": self.rates.agent}

        self.estimator = self.sim2real.estimator
        if self.estimator is not None and description is None:
            raise ValueError("an estimator in the loop needs the robot's description: give the runtime a RobotDescription")
        self._bind(task, self.sim_robot)
        self.action_space = task.action_space
        self.observation_space = task.observation_space
        self._noise_std = self.sim2real.noise_std(int(np.prod(self.observation_space.shape)), task.observation_names())
        self._noisy = bool(np.any(self._noise_std > 0))
        self._observation_low = self.observation_space.low.astype(np.float64)
        self._observation_high = self.observation_space.high.astype(np.float64)
        self._warnings_of = _divergence_counter(self.engine_robot)
        self._actions = ActionQueue(self.sim2real.action_latency)
        config = self.randomizer.config if self.randomizer is not None else None
        self._reports_pushes = config is not None and "push_force" in config.parameters

        self.timings = StepTimings()
        self._tick = 0
        self._wall_start = 0.0
        self._renderer: Any = None
        self._camera: Any = None
        self._viewer: Any = None
        self._reset_done = False
        self._diverged = False
        self._warnings = 0

    # --- gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        engine = self.engines.choose(self.np_random)
        if engine != self.engine:
            self._use_engine(engine)
        task, robot = self.task, self.sim_robot
        if self.randomizer is not None:  # before robot.reset: PyBullet may reload the robot
            self.randomization = self.randomizer.randomize(robot, self.np_random)
            task.randomized(self.randomization)
        task.np_random = self.np_random
        state = task.initial_state()
        if state is None:
            robot.reset()
        else:
            robot.reset(*state)
        if self.estimated is not None:
            self._calibrate_estimator()
        self._tick = 0
        self._actions.clear()
        self._diverged = False
        self._warnings = self._warnings_of()
        task.reset_task()
        self._reset_done = True
        self._wall_start = time.perf_counter()
        observation = self._observe()
        if self.render_mode == "human":
            self.render()
        return observation, self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._reset_done:
            raise RuntimeError("call reset() before step()")
        started = time.perf_counter()
        task, robot = self.task, self.sim_robot
        action = task.validate_action(action)  # raises before anything changes
        actions = self._actions
        latency = actions.latency
        if latency:
            actions.push(self._tick, action)
        else:
            task.set_action(action)
        period = self.rates.physics_per_controller
        tick = self._tick
        end = tick + self.rates.physics_per_agent
        physics_time = controller_time = 0.0
        clock = time.perf_counter
        if latency:
            while tick < end:
                for due in actions.pop_due(tick):
                    task.set_action(due)
                if tick % period == 0:
                    t0 = clock()
                    task.apply_command()
                    controller_time += clock() - t0
                following = min(end, tick - tick % period + period, actions.next_tick())
                t0 = clock()
                robot.step(int(following) - tick)
                physics_time += clock() - t0
                tick = self._tick = int(following)
        else:  # (no action in flight: the same ticks, without the queue's calls)
            apply_command, advance = task.apply_command, robot.step
            while tick < end:
                if tick % period == 0:
                    t0 = clock()
                    apply_command()
                    controller_time += clock() - t0
                following = min(end, tick - tick % period + period)
                t0 = clock()
                advance(following - tick)
                physics_time += clock() - t0
                tick = self._tick = following

        observation = self._observe()
        reward = float(task.get_reward())
        self._diverged = self._diverged or self._warnings_of() > self._warnings
        terminated = bool(task.is_terminated()) or self._diverged
        truncated = bool(task.is_truncated())
        info = self._info()
        timings = self.timings
        timings.physics += physics_time
        timings.controller += controller_time
        timings.agent_steps += 1
        timings.physics_steps += self.rates.physics_per_agent
        timings.total += time.perf_counter() - started
        if self.render_mode == "human":
            self.render()
        if self.real_time_factor is not None:
            self._pace()
        return observation, reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        if self.render_mode == "rgb_array":
            return self._render_frame()
        self._sync_viewer()
        return None

    def close(self) -> None:
        """Close the renderer and viewer, and the engine robots this runtime built (PyBullet servers)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
        self.engines.close()

    # --- runtime state ------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated seconds since the last reset."""
        return self._tick * self.rates.physics_dt

    def describe(self) -> dict[str, Any]:
        """The task's deployment metadata plus this runtime's rates, robot and engine."""
        return {**self.task.describe(), "rates": self.rates.as_dict(), "robot": self.sim_robot.name, "engine": self.engine}

    # --- internals ----------------------------------------------------------------------------
    def _observe(self) -> np.ndarray:
        """The task's observation, plus noise, clipped to the observation space (a new array)."""
        observation = np.asarray(self.task.get_observation(), dtype=np.float64)
        if self._noisy:
            observation = observation + self.np_random.normal(0.0, 1.0, observation.shape) * self._noise_std
        clipped = np.minimum(np.maximum(observation, self._observation_low), self._observation_high)
        return clipped.astype(self.observation_space.dtype)

    def _bind(self, task: Task, robot: Robot) -> None:
        """Bind ``task`` to ``robot``, or, with an estimator in the loop, to ``robot`` seen through it."""
        if self.estimator is None:
            self.estimated = None
            task.bind(robot, self.rates)
        else:
            self.estimated = self.estimator.wrap(robot, self.engines.description)
            task.bind(self.estimated, self.rates, truth=robot)

    def _calibrate_estimator(self) -> None:
        """The estimator's start-up calibration on the reset robot, before the episode and its pushes."""
        assert self.estimated is not None and self.estimator is not None
        robot = self.sim_robot
        perturbed = isinstance(robot, PerturbedRobot)
        if perturbed:
            robot.postpone_pushes()
        calibrate(self.estimated, self.engines.description, self.rates.physics_per_controller, self.estimator.calibration_timeout,
                  self.estimator.gantry_damping)
        if perturbed:
            robot.start_pushes()

    def _use_engine(self, engine: str) -> None:
        """Run the task on ``engine``'s robot from now on (same description: same rates and spaces)."""
        robot = self.engines.robot(engine)
        if _timestep(robot) != self.rates.physics_dt:
            raise ValueError(f"the {engine} robot steps {_timestep(robot)} s, the runtime {self.rates.physics_dt} s")
        self._bind(self.task, robot)
        if self.task.action_space != self.action_space or self.task.observation_space != self.observation_space:
            raise ValueError(f"the task's spaces on {engine} differ from those on {self.engine}")
        self.engine, self.sim_robot, self.engine_robot = engine, robot, self.engines.engine_robot(engine)
        self._warnings_of = _divergence_counter(self.engine_robot)

    def _info(self) -> dict[str, Any]:
        info: dict[str, Any] = {"time": self.time, **self.task.get_info()}
        if self._reports_pushes:
            assert isinstance(self.sim_robot, PerturbedRobot)
            info["push_force"] = self.sim_robot.acting_push_force
            info["pushes"] = self.sim_robot.pushes_applied
        if self._diverged:
            info["physics_diverged"] = True
        return info

    def _pace(self) -> None:
        target = self.time / self.real_time_factor - (time.perf_counter() - self._wall_start)
        if target > 0:
            time.sleep(target)

    def _mujoco(self) -> tuple["mujoco.MjModel", "mujoco.MjData"]:
        model, data = getattr(self.sim_robot, "model", None), getattr(self.sim_robot, "data", None)
        if model is None or data is None:
            raise RuntimeError(f"rendering needs a MuJoCo robot, got {type(self.sim_robot).__name__}")
        return model, data

    def _render_frame(self) -> np.ndarray:
        model, data = self._mujoco()
        if self._renderer is None:
            height, width = self.render_size
            self._renderer = offscreen_renderer(model, height, width)
            self._camera = _default_camera(self.sim_robot, model)
        self._renderer.update_scene(data, camera=self._camera)
        return self._renderer.render()

    def _sync_viewer(self) -> None:
        if self._viewer is None:
            import mujoco.viewer

            model, data = self._mujoco()
            self._viewer = mujoco.viewer.launch_passive(model, data)
        if self._viewer.is_running():  # the user may have closed the window
            self._viewer.sync()


def _divergence_counter(robot: Robot) -> Callable[[], int]:
    """How many times MuJoCo found NaN/huge positions, velocities or accelerations (and reset the state)."""
    data = getattr(robot, "data", None)
    if data is None or not hasattr(data, "warning"):
        return lambda: 0
    import mujoco

    stats = [data.warning[int(w)] for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQACC)]
    return lambda: sum(int(stat.number) for stat in stats)


def _timestep(robot: Robot) -> float:
    """The physics step of the simulated robot: its MuJoCo model's, else its own or its description's."""
    model = getattr(robot, "model", None)
    if model is not None and hasattr(model, "opt"):
        return float(model.opt.timestep)
    for source in (robot, getattr(robot, "description", None)):
        timestep = getattr(source, "timestep", None)
        if timestep is not None:
            return float(timestep)
    raise ValueError(f"cannot tell the physics timestep of {type(robot).__name__}: give it a `timestep` attribute")


def _randomizer(spec: RandomizerSpec, sim2real: SimToReal, description: RobotDescription | None) -> DomainRandomizer | None:
    """The runtime's own randomizer: the user's config with the robot-side sim2real knobs in front."""
    if spec is None and not sim2real.robot_entries():
        return None
    if description is None:
        raise RandomizationError("domain randomization, actuator delay and pushes need a robot with a description")
    base = make_randomizer(spec, description)
    config = sim2real.merged_into(base.config if base is not None else None, description)
    return DomainRandomizer(config, description)


def _base_link(robot: Robot) -> str:
    description = getattr(robot, "description", None)
    if description is None:
        raise ValueError(f"{type(robot).__name__} has no description: cannot tell its base link")
    return description.base_link


def _default_camera(robot: Robot, model: "mujoco.MjModel") -> "mujoco.MjvCamera":
    """A camera following the base of a floating robot, or framing a fixed one."""
    import mujoco

    camera = mujoco.MjvCamera()
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, _base_link(robot))
    camera.azimuth, camera.elevation = 135.0, -15.0
    if robot.floating_base and base >= 0:
        camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        camera.trackbodyid = base
        camera.distance = 2.5
    else:
        camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        camera.azimuth, camera.elevation = 90.0, -10.0
        camera.lookat[:] = model.stat.center
        camera.distance = 1.3 * model.stat.extent
    return camera
