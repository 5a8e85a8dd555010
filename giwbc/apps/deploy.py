"""``giwbc deploy``: run a controller (and optionally a policy) on CAN actuators, or rehearse it on
the actuator emulator.

Procedure (:func:`deploy`):

1. load the robot description and, with ``--policy``, the policy's metadata; check it against the
   robot (joint names and order, rates: :func:`check_policy_metadata`, a plain-dict check);
2. load the hardware plan and check it (motors for exactly the robot's joints, torque ranges,
   bus capacity at the control rate); print the bus loads;
3. ``--emulate``: start the :class:`~giwbc.emulation.emulator.ActuatorEmulator` on ``virtual`` buses,
   in lockstep with the control loop (deterministic, can run faster than real time), or with
   ``--emulator process`` in its own process on ``giwbc-unix`` channels, on its own real-time
   clock (:mod:`giwbc.emulation.process`: the loop then pays only for its own work, as with
   real motors, and takes each cycle's replies at the next cycle); otherwise open the configured
   buses;
4. build the CAN robot (IMU from the plan's source) and, when the controller needs a base state,
   wrap it: ``EstimatedRobot(CanRobot(...))`` (the base from the state estimator); the task
   (``stand``: a controller holds the robot, no action; with a policy: the policy's task), the
   run log, and run the :class:`~giwbc.runtimes.realtime.RealtimeRuntime` for ``--seconds``
   (with a state estimator, after the start-up ramp the robot holds still until the estimator's
   IMU calibration is done: phase ``calibrate``, :mod:`giwbc.runtimes.phases`);
5. report (with the IMU calibration found, also in the run log's ``calibration`` event): exit
   code 0 on a clean run, non-zero with the cause on a fault (128 + the signal's number for SIGINT, SIGTERM, SIGHUP, SIGQUIT: 130, 143, 129, 131; 130 for a ``KeyboardInterrupt``
   inside the loop; 1 for other faults, the watchdog's included; 2 for configuration errors).

Real buses: before anything is sent, the SocketCAN pre-flight (:mod:`giwbc.hal.preflight`) checks
every ``socketcan`` interface of the plan and stops with the ``ip link`` commands that fix it
(``--no-preflight`` skips it). Before enabling, the runtime reads every joint without torque and
refuses to start when one is outside its limits (a wrong sign or zero offset).
``--first-run``: a robot on a gantry: reduced torque and gains, tighter supervisor thresholds
(:class:`giwbc.hal.bringup.FirstRunLimits`); with ``--emulate`` the emulated robot hangs on a gantry.
``--emulate --imu serial|can``: the emulator sends its IMU as an Xsens MTi on a pseudo-terminal or
as CAN frames, read through the real drivers.

Walking: ``--controller walk --vx 0.3 [--vy --yaw-rate] [--step-in-place]``
(:mod:`giwbc.apps.deploy_walk`): the walking WBC on the estimated robot, standing for ``--walk-delay``
s after the start-up, then walking. ``--emulate --unpaced``: the lockstep emulator as fast as the
machine allows (a rehearsal on a machine too slow for the loop and the physics in real time).
A walking policy (metadata ``env_id`` ``giwbc/G1Walk-v0``; task ``walk``, the default for it):
``--policy g1_walk_residual.onnx --vx 0.3``: the same walker on the estimated robot, the policy's
residuals (where and when the feet land, ...) at its agent rate
(:class:`giwbc.apps.deploy_walk.WalkPolicyTask`). Refused: a walking policy with ``--task
balance`` or ``--controller pd``, a balance policy with ``--task walk``, walking options for a
task that does not walk, and the walking policy without the state estimator.

Fault rehearsal: ``--emulate --fault KIND`` injects one fault of the fault table
(:data:`giwbc.runtimes.faults.FAULT_CASES`) ``--fault-at`` seconds after the start-up ramp, for a
person to watch what the supervisor does (``DeployOptions.faults`` takes any number).

IMU: ``--imu-profile`` names the IMU's class (:data:`giwbc.robot.noise.IMU_PROFILES`): the
estimator is set up for it (``mems``, ``cheap``: no orientation output, tilt from gravity and the
feet) and, with ``--emulate``, the emulated IMU carries its errors (turn-on biases drawn from the
emulator's seed, noise, latency, dropouts).
"""

from __future__ import annotations

import argparse
import copy
import inspect
import json
import math
import os
import sys
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium
import numpy as np
from giwbc.apps.live import DEFAULT_PORT, LiveServer, require_foxglove
from giwbc.apps.live import HOST as LIVE_HOST
from giwbc.apps.scene import SceneChannels
from giwbc.apps.deploy_walk import WalkCommand, WalkHold, WalkPolicyTask, add_walk_arguments, walk_command
from giwbc.apps.deploy_hardware import check_interfaces, choose_imu, first_run_settings, imu_counters, on_channels, with_gantry

from giwbc.control.balance import make_balance_controller
from giwbc.emulation import ActuatorEmulator, EmulatorConfig, FaultInjection
from giwbc.emulation.process import EmulatorProcess
from giwbc.envs import RUNTIME_OPTIONS
from giwbc.errors import DeployError
from giwbc.estimation.calibration import CalibrationReport, StandstillConfig
from giwbc.estimation.estimated_robot import EstimatedRobot
from giwbc.estimation.estimator import EstimatorConfig, StateEstimator
from giwbc.hal.can_robot import CanRobot
from giwbc.hal.hardware import HardwareConfigError, load_hardware
from giwbc.hal.imu import imu_source_for
from giwbc.policy import OnnxPolicy, PolicyFormatError
from giwbc.hal.safety import SafetyConfig
from giwbc.robot.description import RobotDescription, RobotDescriptionError, load
from giwbc.robot.noise import IMU_PROFILES, SensorNoiseConfig
from giwbc.robot.standing import PdHold
from giwbc.runlog import RunLogWriter
from giwbc.runtimes.faults import HostFaults, fault_case
from giwbc.runtimes.phases import StartupConfig
from giwbc.runtimes.realtime import RealtimeRuntime, RunResult
from giwbc.tasks.balance import G1Balance
from giwbc.tasks.standing import StandingTask

if TYPE_CHECKING:
    import mujoco

TASKS = ("stand", "balance", "walk")
WALK_ENV = "giwbc/G1Walk-v0"  # a walking policy's env_id: the deploy task "walk"
CONTROLLERS = ("wbc", "pd", "walk")
EMULATOR_MODES = ("lockstep", "process")


def _runtime_keys() -> frozenset[str]:
    """Env kwargs that configure the simulated runtime or ``gymnasium.make``'s wrappers
    (``max_episode_steps``, ...), not the task: the deployment drops them."""
    named = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    make_options = {name for name, p in inspect.signature(gymnasium.make).parameters.items() if p.kind in named} - {"id"}
    return frozenset({"robot", "agent_rate", *RUNTIME_OPTIONS, *make_options})


def scene_channels(description: RobotDescription, joint_names: Sequence[str], rate: float, port: int | None) -> SceneChannels | None:
    """The run log's 3D scene at ``rate`` Hz (0: none), streamed live on ``port`` if given."""
    if rate <= 0 and port is None:
        return None
    live = LiveServer(port) if port is not None else None
    return SceneChannels(description, joint_names, rate=rate if rate > 0 else 1.0, live=live, log=rate > 0)


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
    or a ``.json`` holding metadata only (a rehearsal with zero actions)."""
    path = Path(path)
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


def make_controller(name: str, description: RobotDescription, walk: WalkCommand | None = None) -> Any:
    """A deployment controller by name; ``walk``: the ``walk`` controller's command (default: stand)."""
    if name == "walk":
        return WalkHold(description, walk)
    if name == "pd":
        return PdHold(description)
    if name == "wbc":
        return WbcHold(description)
    raise DeployError(f"unknown controller {name!r}; choose from {', '.join(CONTROLLERS)}")


# ----------------------------------------------------------------------------- the procedure
@dataclass(frozen=True)
class DeployOptions:
    """What ``giwbc deploy`` does (see the module docstring)."""

    robot: str = "g1"
    policy: str | None = None
    task: str | None = None  # default: with a policy its own ("walk" for a G1Walk-v0 policy, else "balance"), "stand" without
    controller: str = "wbc"
    hardware: str | None = None  # default: the robot folder's hardware.toml
    emulate: bool = False
    emulator_mode: str = "lockstep"  # or "process": the emulator in its own process (module docstring)
    seconds: float = 10.0
    control_rate: float = 500.0
    agent_rate: float = 50.0
    log: str | None = None  # default: runs/deploy-<robot>-<time>.mcap
    log_every: int = 1
    realtime: bool = True
    estimator: bool | None = None  # None: only when the controller needs the base state (wbc, balance)
    startup: StartupConfig | None = None
    safety: SafetyConfig | None = None
    emulator: EmulatorConfig | None = None
    faults: tuple[FaultInjection, ...] = ()  # injected into the emulator (rehearsals, tests)
    reply_timeout: float = 0.8e-3
    rt_priority: int | None = None  # SCHED_FIFO priority of the control loop (None: the default scheduler)
    imu: str | None = None  # with emulate: "emulated", "serial" or "can" (the device the emulator imitates); None: the plan's
    preflight: bool = True  # SocketCAN pre-flight on real buses
    first_run: bool = False  # a robot on a gantry: reduced limits (FirstRunLimits)
    emulated_hardware: str | None = None  # with emulate: the emulated robot's true wiring (default: the plan), e.g. to rehearse a wrong sign
    scene_rate: float = 50.0  # Hz of the 3D scene (link transforms, contact forces) in the log; 0: none
    foxglove_port: int | None = None  # also stream the scene to Foxglove on this loopback port (the logger's process)
    imu_profile: str | None = None  # the IMU's class (giwbc.robot.noise.IMU_PROFILES): the emulated IMU's errors, the estimator's setup
    walk: WalkCommand | None = None  # the walk controller's command (None: stand)


@dataclass
class DeployOutcome:
    """What happened: the runtime's result, the exit code and message, the log, and (emulated)
    the ground-truth standing summary of the running phase."""

    exit_code: int
    message: str
    result: RunResult | None = None
    log_path: str | None = None
    bus_loads: list[str] = field(default_factory=list)
    standing: dict[str, float] | None = None
    emulator: ActuatorEmulator | EmulatorProcess | None = None
    fault_onsets: dict[str, float] = field(default_factory=dict)  # host-side injected faults: robot time each first acted
    imu_counters: dict[str, int] | None = None  # a serial or CAN IMU driver's counters (samples, checksum errors, ...)
    calibration: CalibrationReport | None = None  # what the state estimator's start-up calibration found
    walking: dict[str, Any] | None = None  # the walk controller's counts: steps (touch-downs), single-support ticks


def deploy(
    options: DeployOptions,
    *,
    policy: Callable[[np.ndarray], np.ndarray] | None = None,
    policy_metadata: Mapping[str, Any] | None = None,
    model: mujoco.MjModel | None = None,
    description: RobotDescription | None = None,
    out: Callable[[str], None] | None = print,
) -> DeployOutcome:
    """Run a deployment (see the module docstring). ``policy``/``policy_metadata`` give a policy
    directly instead of ``options.policy``; ``model``: the MjModel the emulator uses (a copy is
    taken; tests pass a cached one). Never raises for faults or configuration errors."""
    say = out or (lambda message: None)
    try:
        return _deploy(options, policy, policy_metadata, model, description, say)
    except DeployError as error:
        say(f"giwbc deploy: error: {error}")
        return DeployOutcome(2, str(error))
    except Exception as error:  # noqa: BLE001 - setup bugs: reported, never a traceback at the operator
        message = f"internal error before or after the run: {type(error).__name__}: {error}"
        say(f"giwbc deploy: {message}\n{traceback.format_exc(limit=6)}")
        return DeployOutcome(1, message)


def _deploy(options: DeployOptions, policy: Any, metadata: Any, model: Any, description: Any, say: Callable[[str], None]) -> DeployOutcome:
    try:
        description = description or load(options.robot)
    except RobotDescriptionError as error:
        raise DeployError(str(error)) from error
    if options.emulator_mode not in EMULATOR_MODES:
        raise DeployError(f"emulator mode must be one of {', '.join(EMULATOR_MODES)}, got {options.emulator_mode!r}")
    if not options.realtime and not options.emulate:
        raise DeployError("real motors run in real time: an unpaced run (--unpaced, realtime=False) needs --emulate")
    if options.emulate and options.emulator_mode == "process" and not options.realtime:
        raise DeployError("the emulator process runs in real time: an unpaced run (realtime=False) needs the lockstep emulator")

    agent_rate = options.agent_rate
    if options.policy is not None and policy is None:
        policy, metadata = load_policy(options.policy)
    if metadata is not None:
        agent_rate = check_policy_metadata(metadata, description, options.control_rate)
    task_name = _task_name(options, metadata, policy)
    if task_name == "walk" and (options.estimator is False or not description.floating_base):
        raise DeployError("the walking policy walks on the state estimator's base state: it needs a floating base and the estimator")


    hardware = Path(options.hardware) if options.hardware else description.folder / "hardware.toml"
    names = description.joint_names
    try:
        plan = load_hardware(
            hardware, options.control_rate, joint_names=names,
            effort_limits=dict(zip(names, description.effort_limits)), interface="virtual" if options.emulate else None,
        )  # fmt: skip
    except HardwareConfigError as error:
        raise DeployError(str(error)) from error
    plan = choose_imu(plan, options.imu, options.emulate, options.emulator_mode)
    loads = [str(load_) for load_ in plan.loads.values()]
    say(f"hardware {hardware}: {len(plan.motors)} motors on {len(plan.buses)} buses at {options.control_rate:g} Hz")
    for line in loads:
        say(f"  {line}")


    sensors = _imu_profile(options)
    host_faults = HostFaults(options.faults)
    if host_faults and not options.emulate:
        raise DeployError("injected faults are for rehearsals: they need --emulate")
    emulator = None
    can_robot: CanRobot | None = None
    log = None
    runtime = None
    imu = None
    try:
        first_run, safety = None, options.safety
        if options.first_run:
            first_run, safety = first_run_settings(safety, say)
        if options.emulate:
            config = options.emulator or EmulatorConfig()
            if sensors is not None and config.imu is None:
                config = replace(config, imu=sensors)
            if first_run is not None:
                config = with_gantry(config)
            if options.faults:
                config = replace(config, faults=tuple(config.faults) + tuple(options.faults))
            if options.emulator_mode == "process":
                rt = None if options.rt_priority is None else max(1, options.rt_priority - 1)  # just below the loop
                emulator = EmulatorProcess(plan, description, config, rt_priority=rt)
                host_plan, peer = emulator.host_plan(), None
                say("emulated actuators in their own process on giwbc-unix channels (real time; replies read at the next cycle)")
            else:
                truth = plan
                if options.emulated_hardware is not None:
                    try:
                        truth = load_hardware(options.emulated_hardware, options.control_rate, joint_names=names, interface="virtual")
                    except HardwareConfigError as error:
                        raise DeployError(str(error)) from error
                    truth = truth.with_imu(plan.imu)
                emulator = ActuatorEmulator(truth, description, config, model=copy.copy(model) if model is not None else None)
                host_plan, peer = on_channels(plan, emulator.host_plan()), emulator
                say("emulated actuators on python-can virtual buses (lockstep with the control loop)")
            imu = imu_source_for(host_plan.imu, emulator.imu_channel)
        else:
            host_plan, peer = plan, None
            try:
                imu = imu_source_for(plan.imu)
            except (HardwareConfigError, ValueError) as error:
                raise DeployError(str(error)) from error
            if options.preflight:
                check_interfaces(plan, say)
        if plan.imu.source != "emulated":
            say(f"IMU: {plan.imu.source} ({host_plan.imu.device if plan.imu.source == 'serial' else 'bus ' + str(plan.imu.bus)}), "
                "read through its driver")  # fmt: skip
        estimator = None
        wants_estimator = options.estimator if options.estimator is not None else not (task_name == "stand" and options.controller == "pd")

        if wants_estimator and description.floating_base:
            # The start-up holds the robot still anyway: a 4 s calibration window (16 blocks, not 0.75 s) averages the
            # gyro's noise to ~0.2 mrad/s per axis (the held robot's slow sway is read from the leg encoders).
            standstill = StandstillConfig(startup_blocks=16)
            estimator = StateEstimator(description, EstimatorConfig.for_sensors(sensors, standstill=standstill) if sensors is not None
                                       else EstimatorConfig(standstill=standstill))  # fmt: skip
        clock: list[Callable[[], float]] = []  # robot time for host-side faults (set once the robot exists)
        if isinstance(emulator, ActuatorEmulator):
            clock.append(lambda: emulator.time)  # lockstep: the emulator is at the cycle's time when the host sends
        links = host_faults.links(host_plan, lambda: clock[0]() if clock else 0.0)
        try:
            can_robot = CanRobot(description, host_plan, imu=imu, peer=peer, reply_timeout=options.reply_timeout,
                                 wait_for_replies=not (options.emulate and options.emulator_mode == "process"), links=links)
        except Exception as error:  # noqa: BLE001 - python-can raises interface-specific errors
            raise DeployError(f"cannot open the CAN buses: {type(error).__name__}: {error}") from error
        if first_run is not None:
            can_robot.reduce_limits(first_run.torque_fraction, first_run.gain_fraction)
        robot = can_robot if estimator is None else EstimatedRobot(can_robot, estimator)

        if not clock:
            clock.append(lambda: robot.time() + 1.0 / options.control_rate)
        if task_name == "stand":
            task: Any = StandingTask(make_controller(options.controller, description, options.walk), description.default_positions)
        elif task_name == "walk":
            task = _walk_task(description, metadata, options.walk)
        else:
            task = _balance_task(description, metadata, options.controller)
        if host_faults:
            try:
                host_faults.wrap_task(task, robot)
            except ValueError as error:
                raise DeployError(str(error)) from error
            if any(f.kind == "policy_nan" for f in host_faults.faults) and policy is None:
                raise DeployError("the policy_nan fault needs a policy (--policy)")
            policy = host_faults.wrap_policy(policy, robot)
        log_path = Path(options.log) if options.log else Path("runs") / f"deploy-{description.name}-{time.strftime('%Y%m%d-%H%M%S')}.mcap"
        log = RunLogWriter(log_path, names, {
            "robot": description.name, "hardware": str(hardware), "emulate": options.emulate, "task": task_name,
            "controller": options.controller, "policy": options.policy, "control_rate": options.control_rate,
            "agent_rate": agent_rate, "seconds": options.seconds, "bus_loads": loads,
        }, extension=scene_channels(description, names, options.scene_rate, options.foxglove_port))  # fmt: skip
        if options.foxglove_port is not None:
            say(f"Foxglove: open a connection to ws://{LIVE_HOST}:{options.foxglove_port} (the scene at 30 Hz, from the logger's process)")
        runtime = RealtimeRuntime(
            task, robot, agent_rate=agent_rate, controller_rate=options.control_rate, safety=safety,
            startup=options.startup, log=log, log_every=options.log_every, realtime=options.realtime,
            rt_priority=options.rt_priority,
        )  # fmt: skip
        if metadata is not None:
            _check_layout(metadata, task)
        say(f"running {task_name} ({'walker' if task_name == 'walk' else options.controller}) for {options.seconds:g} s"
            + (" with the policy" if policy else ""))
        result = runtime.run(policy, options.seconds)
        counters = imu_counters(imu)
        if counters is not None:
            say("IMU driver: " + ", ".join(f"{k} {v}" for k, v in counters.items()))
    finally:
        if host_faults:
            host_faults.release()  # a driver blocked on purpose: let the abandoned loop's thread leave
            if runtime is not None and runtime._loop_thread is not None:
                runtime._loop_thread.join(1.0)
        if can_robot is not None:
            can_robot.close()
        if hasattr(imu, "close") and (emulator is None or imu is not emulator.imu_channel):
            imu.close()  # a serial IMU's port (the emulator's channel is the emulator's to close)
        if emulator is not None:
            emulator.close()
        if log is not None:
            log.close()

    calibration = estimator.calibration if estimator is not None else None
    if calibration is not None:
        say(calibration.summary())
    elif estimator is not None and estimator.config.calibrate:
        say(f"IMU not calibrated: the state estimator was waiting for {estimator.waiting_for}")
    standing = None
    if emulator is not None and description.floating_base:
        standing = _standing(emulator, result)
    timing = result.timing
    pacing = (
        f"period error p50 {_us(timing['period_error_us']['p50'])} p99 {_us(timing['period_error_us']['p99'])}, "
        f"overruns {timing['overruns']}, skipped slots {timing['skipped_slots']}"
        if options.realtime else "not paced (as fast as possible)"
    )  # fmt: skip
    say(f"{result.cycles} cycles, {result.robot_time:.2f} s robot time in {result.wall_time:.2f} s; {pacing}")
    if options.realtime and options.emulate and options.emulator_mode == "lockstep" and timing["overruns"]:
        say("  (lockstep: the loop also runs the emulator's physics and firmware; --emulator process times the loop as on hardware)")
    if standing is not None:
        say(
            f"emulated robot while running: base height {standing['min_height']:.3f}..{standing['max_height']:.3f} m, "
            f"max tilt {math.degrees(standing['max_tilt']):.1f} deg ({'stood' if standing['stood'] else 'FELL'}), "
            f"base moved {standing['dx']:+.2f} m forward, {standing['dy']:+.2f} m sideways"
        )
    walking = None
    hold = task.hold if isinstance(task, WalkPolicyTask) else task.controller if isinstance(task, StandingTask) else None
    if isinstance(hold, WalkHold):
        walker = hold
        walking = {"steps": walker.steps, "single_support_ticks": walker.single_support_ticks, "notes": list(walker.notes)}
        say(f"walking: {walker.steps} steps" + (f" (command: {'; '.join(walker.notes)})" if walker.notes else ""))
    say(f"log: {log.path}")
    if result.ok:
        message = "clean run: motors ramped to damping and switched off"
    elif result.fault is not None and result.fault.kind.value == "watchdog":
        unreachable = (runtime.emergency or {}).get("unreachable_buses") or []
        message = (f"stopped by a fault: {result.fault}; the watchdog switched the motors to damping then off"
                   + (f" (buses {', '.join(unreachable)} unreachable: their motors are left to their own timeout)" if unreachable else ""))
    else:
        message = f"stopped by a fault: {result.fault}; motors in damping then off"
        if result.unconfirmed_off:
            message += f" (not confirmed by {', '.join(result.unconfirmed_off)}: left to their own timeout)"
    if len(result.faults) > 1:
        message += "; also: " + ", ".join(f.kind.value for f in result.faults[1:])
    say(message)
    return DeployOutcome(
        result.exit_code, message, result, str(log.path), loads, standing, emulator, dict(host_faults.onsets), counters, calibration, walking
    )


def _imu_profile(options: DeployOptions) -> SensorNoiseConfig | None:
    """The IMU's sensor model: the named profile, else the emulator's configured IMU, else None."""
    if options.imu_profile is not None:
        try:
            return SensorNoiseConfig.profile(options.imu_profile)
        except ValueError as error:
            raise DeployError(str(error)) from error
    return options.emulator.imu if options.emulate and options.emulator is not None else None


def _task_name(options: DeployOptions, metadata: Mapping[str, Any] | None, policy: Any) -> str:
    """The task to run (see :class:`DeployOptions`); :class:`DeployError` for combinations that cannot run."""
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
    if options.walk is not None and options.walk.moves and task_name != "walk" and options.controller != "walk":
        raise DeployError("--vx/--vy/--yaw-rate/--step-in-place need --controller walk or a walking policy")
    return task_name


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


def _check_layout(metadata: Mapping[str, Any], task: Any) -> None:
    for key, names in (("observation_names", task.observation_names()), ("action_names", task.action_names())):
        if list(metadata.get(key) or []) != list(names):
            raise DeployError(f"the policy's {key} differ from the task's ({len(metadata.get(key) or [])} vs {len(names)} entries)")


def _standing(emulator: ActuatorEmulator | EmulatorProcess, result: RunResult) -> dict[str, float] | None:
    """Ground truth over the running phase: did the emulated robot stay up?"""
    start = result.phase_times.get("running")
    if start is None:
        return None
    stop = result.phase_times.get("shutdown", result.phase_times.get("damping", math.inf))
    rows = emulator.truth_between(start, stop)
    if not len(rows):
        return None
    heights, tilts = rows[:, 1], rows[:, 2]
    stood = bool(tilts.max() < math.radians(10.0) and heights.min() > 0.8 * heights[0])
    moved = rows[:, 3:5] - rows[0, 3:5]  # world frame (the emulated robot starts facing +x)
    return {"min_height": float(heights.min()), "max_height": float(heights.max()), "max_tilt": float(tilts.max()),
            "seconds": float(rows[-1, 0] - rows[0, 0]), "stood": stood, "dx": float(moved[-1, 0]), "dy": float(moved[-1, 1]),
            "max_excursion": float(np.hypot(moved[:, 0], moved[:, 1]).max())}  # fmt: skip


def _us(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.0f} us"


# ----------------------------------------------------------------------------- command line
def add_deploy_command(commands: Any) -> argparse.ArgumentParser:
    """Add ``giwbc deploy`` to an argparse subparsers object."""
    parser = commands.add_parser("deploy", help="run on CAN actuators, or rehearse on the emulator (--emulate)")
    parser.add_argument("--robot", default="g1")
    parser.add_argument("--policy", default=None, help="policy .onnx (or its metadata .json); optional")
    parser.add_argument("--task", choices=TASKS, default=None,
                        help="default: with a policy its own (walk for a G1Walk-v0 policy, else balance), stand without")
    parser.add_argument("--controller", choices=CONTROLLERS, default="wbc", help="whole-body QP, joint-PD hold, or the walking WBC")
    add_walk_arguments(parser)
    parser.add_argument("--hardware", default=None, help="hardware.toml (default: the robot folder's)")
    parser.add_argument("--emulate", action="store_true", help="rehearse on the actuator emulator instead of the configured buses")
    parser.add_argument("--emulator", choices=EMULATOR_MODES, default="lockstep",
                        help="with --emulate: in the control loop's thread on virtual buses (lockstep), or in its own process (real time)")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of control after the start-up ramp")
    parser.add_argument("--unpaced", action="store_true",
                        help="with --emulator lockstep: as fast as the machine allows, in the emulator's time (no real-time pacing)")
    parser.add_argument("--rate", type=float, default=500.0, help="control rate, Hz")
    parser.add_argument("--log", default=None, help="run log (.mcap); default runs/deploy-<robot>-<time>.mcap")
    parser.add_argument("--ramp", type=float, default=2.0, help="start-up ramp to the default pose, s")
    parser.add_argument("--rt-priority", type=int, default=None, help="SCHED_FIFO priority of the control loop (needs CAP_SYS_NICE)")
    parser.add_argument("--json", action="store_true", help="print one JSON summary at the end")
    parser.add_argument("--imu", choices=("emulated", "serial", "can"), default=None,
                        help="with --emulate: the IMU device the emulator imitates, read through the real driver (default: the plan's)")
    parser.add_argument("--no-preflight", action="store_true", help="skip the SocketCAN pre-flight check of the interfaces")
    parser.add_argument("--emulated-hardware", default=None,
                        help="with --emulate: the emulated robot's true wiring, when it differs from --hardware (calibration rehearsals)")
    parser.add_argument("--first-run", action="store_true",
                        help="robot on a gantry: reduced torque and gains, tighter fall and limit thresholds")
    parser.add_argument("--foxglove", action="store_true",
                        help="stream the robot in 3D to Foxglove over a loopback WebSocket (needs foxglove-sdk)")
    parser.add_argument("--foxglove-port", type=int, default=DEFAULT_PORT, help="the WebSocket's port")
    parser.add_argument("--scene-rate", type=float, default=DeployOptions.scene_rate,
                        help="Hz of the 3D scene (transforms, joint states, contact forces) in the log; 0: none")
    parser.add_argument("--fault", default=None, metavar="KIND",
                        help="with --emulate: inject one fault of the fault table (giwbc.runtimes.faults.FAULT_CASES), e.g. bus_off")
    parser.add_argument("--fault-at", type=float, default=1.0, help="seconds after the start-up ramp at which --fault starts")
    parser.add_argument("--imu-profile", choices=sorted(IMU_PROFILES), default=None,
                        help="the IMU's class: with --emulate the emulated IMU's errors (mems, cheap: no orientation output); "
                             "sets up the state estimator for it")  # fmt: skip
    parser.set_defaults(run=run_deploy_command)
    return parser


def run_deploy_command(args: argparse.Namespace) -> int:
    startup = StartupConfig(ramp_time=args.ramp)
    faults: tuple[Any, ...] = ()
    if getattr(args, "fault", None):
        try:
            case = fault_case(args.fault)
        except ValueError as error:
            print(f"giwbc deploy: error: {error}", file=sys.stderr)
            return 2
        faults = case.injections(startup.settle_time + startup.ramp_time + args.fault_at)
    if args.foxglove:
        require_foxglove()  # before the motors, not after
    try:
        walk = walk_command(args)
    except DeployError as error:
        print(f"giwbc deploy: error: {error}", file=sys.stderr)
        return 2
    options = DeployOptions(
        robot=args.robot, policy=args.policy, task=args.task, controller=args.controller, hardware=args.hardware,
        emulate=args.emulate, emulator_mode=args.emulator, seconds=args.seconds, control_rate=args.rate, log=args.log, realtime=not args.unpaced,
        startup=startup, rt_priority=args.rt_priority, faults=faults, imu=args.imu, preflight=not args.no_preflight,
        first_run=args.first_run, emulated_hardware=args.emulated_hardware, scene_rate=args.scene_rate,
        foxglove_port=args.foxglove_port if args.foxglove else None, imu_profile=args.imu_profile, walk=walk,
    )  # fmt: skip
    outcome = deploy(options, out=(lambda m: print(m, file=sys.stderr)) if args.json else print)
    if args.json:
        result = outcome.result
        print(json.dumps({
            "exit_code": outcome.exit_code, "message": outcome.message, "log": outcome.log_path,
            "fault": None if result is None or result.fault is None else result.fault.as_dict(),
            "faults": [] if result is None else [f.kind.value for f in result.faults],
            "timing": None if result is None else result.timing, "standing": outcome.standing, "walking": outcome.walking,
            "calibration": None if outcome.calibration is None else outcome.calibration.as_dict(),
        }))  # fmt: skip
    elif outcome.exit_code:
        print(f"giwbc deploy: {outcome.message}", file=sys.stderr)
    if outcome.result is not None and outcome.result.loop_abandoned:
        # The loop's thread is stuck in a driver (the watchdog stopped the motors): leave without
        # waiting for it at interpreter shutdown.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(outcome.exit_code)
    return outcome.exit_code


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m giwbc.apps.deploy ...`` (the same as ``giwbc deploy ...``)."""
    parser = argparse.ArgumentParser(prog="giwbc")
    add_deploy_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["deploy", *(sys.argv[1:] if argv is None else argv)])
    return int(args.run(args))


if __name__ == "__main__":
    sys.exit(main())
