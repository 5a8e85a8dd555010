"""The ``giwbc deploy`` procedure (:func:`deploy`): run a controller (and optionally a policy) on CAN
actuators, or rehearse it on the actuator emulator. The command line is :mod:`giwbc.apps.deploy`,
the choice of the task and controller (and its refusals) :mod:`giwbc.apps.deploy_setup`.

Procedure (:func:`deploy`):

1. load the robot description and, with ``--policy``, the policy's metadata; check it against the
   robot (joint names and order, rates: :func:`~giwbc.apps.deploy_setup.check_policy_metadata`, a
   plain-dict check); choose the task (:func:`~giwbc.apps.deploy_setup.choose_task`);
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
   run log (with a walking controller, the walker's state at each tick: ``/walker``,
   :mod:`giwbc.apps.deploy_walk_log`), and run the :class:`~giwbc.runtimes.realtime.RealtimeRuntime`
   for ``--seconds`` (with a state estimator, after the start-up ramp the robot holds still until the estimator's
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
(:class:`giwbc.apps.deploy_walk.WalkPolicyTask`). The combinations refused:
:mod:`giwbc.apps.deploy_setup`.

Fault rehearsal: ``--emulate --fault KIND`` injects one fault of the fault table
(:data:`giwbc.runtimes.faults.FAULT_CASES`) ``--fault-at`` seconds after the start-up ramp, for a
person to watch what the supervisor does (``DeployOptions.faults`` takes any number).

DDS: ``--transport dds`` (:mod:`giwbc.apps.deploy_dds`): a G1 through Unitree's low-level DDS interface
(``rt/lowcmd`` / ``rt/lowstate``, the plan ``hardware_dds.toml``), the same runtime and supervisor on a
:class:`~giwbc.hal.dds.robot.DdsRobot`; with ``--emulate --emulator process`` the DDS emulator in its
own process on loopback (:mod:`giwbc.emulation.dds_emulator`); ``--fault dds_...`` its fault rows.

IMU: ``--imu-profile`` names the IMU's class (:data:`giwbc.robot.noise.IMU_PROFILES`): the
estimator is set up for it (``mems``, ``cheap``: no orientation output, tilt from gravity and the
feet) and, with ``--emulate``, the emulated IMU carries its errors (turn-on biases drawn from the
emulator's seed, noise, latency, dropouts).
"""


from __future__ import annotations

import copy
import math
import os
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.apps.deploy_dds import check_transport, default_hardware, open_dds, split_faults
from giwbc.apps.deploy_diagnosis import fault_summary, load_average, overload_note
from giwbc.apps.deploy_hardware import check_interfaces, choose_imu, first_run_settings, imu_counters, on_channels, with_gantry
from giwbc.apps.deploy_options import EMULATOR_MODES, DeployOptions, DeployOutcome
from giwbc.apps.deploy_setup import build_task, check_layout, check_policy_metadata, choose_task, load_policy, walking_hold, wants_estimator
from giwbc.apps.live import HOST as LIVE_HOST
from giwbc.apps.live import LiveServer
from giwbc.apps.scene import SceneChannels
from giwbc.emulation import ActuatorEmulator, EmulatorConfig
from giwbc.emulation.process import EmulatorProcess
from giwbc.errors import ConfigError, DeployError
from giwbc.estimation.calibration import StandstillConfig
from giwbc.estimation.estimated_robot import EstimatedRobot
from giwbc.estimation.estimator import EstimatorConfig, StateEstimator
from giwbc.hal.can_robot import CanRobot
from giwbc.hal.dds.plan import DdsPlan
from giwbc.hal.hardware import HardwareConfigError, load_hardware
from giwbc.hal.imu import imu_source_for
from giwbc.plants import Plant, plant_label, resolve_plant
from giwbc.apps.deploy_walk_log import WalkerRecorder
from giwbc.robot.description import RobotDescription, RobotDescriptionError, load
from giwbc.robot.noise import SensorNoiseConfig
from giwbc.runlog import RunLogWriter
from giwbc.runtimes.faults import HostFaults
from giwbc.runtimes.os_settings import probe_rt_priority
from giwbc.runtimes.realtime import RealtimeRuntime, RunResult

if TYPE_CHECKING:
    import mujoco


def scene_channels(description: RobotDescription, joint_names: Sequence[str], rate: float, port: int | None) -> SceneChannels | None:
    """The run log's 3D scene at ``rate`` Hz (0: none), streamed live on ``port`` if given."""
    if rate <= 0 and port is None:
        return None
    live = LiveServer(port) if port is not None else None
    return SceneChannels(description, joint_names, rate=rate if rate > 0 else 1.0, live=live, log=rate > 0)


def emulated_plant(options: DeployOptions, description: RobotDescription, model: Any) -> Plant | None:
    """The emulated robot's plant (``options.plant``), built and checked before anything starts
    (an unknown variant, a bad file or a plant that does not fit the robot: one line, exit 2)."""
    if options.plant is None:
        return None
    if model is not None:
        raise DeployError("give the emulated robot's plant once: options.plant or the model argument, not both")
    try:
        return resolve_plant(description, options.plant)
    except RobotDescriptionError as error:  # PlantMismatchError included
        raise DeployError(f"--plant {options.plant}: {error}") from error


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
    except (DeployError, ConfigError) as error:  # refused before anything started: the caller prints it (once)
        return DeployOutcome(2, str(error))
    except Exception as error:  # noqa: BLE001 - setup bugs: reported, never a traceback at the operator
        message = f"internal error before or after the run: {type(error).__name__}: {error}"
        if os.environ.get("GIWBC_TRACEBACK"):  # for a developer chasing it
            say(traceback.format_exc(limit=8))
        return DeployOutcome(1, message + " (a bug: GIWBC_TRACEBACK=1 prints where)")


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
    task_name = choose_task(options, metadata, policy, description)

    hardware = Path(options.hardware) if options.hardware else default_hardware(description, options.transport)
    names = description.joint_names
    try:
        plan = load_hardware(
            hardware, options.control_rate, joint_names=names,
            effort_limits=dict(zip(names, description.effort_limits)), interface="virtual" if options.emulate else None, allow_dds=True,
        )  # fmt: skip
    except HardwareConfigError as error:
        raise DeployError(str(error)) from error
    check_transport(plan, options.transport, hardware)
    dds = isinstance(plan, DdsPlan)
    if not dds:
        plan = choose_imu(plan, options.imu, options.emulate, options.emulator_mode)
    plant = emulated_plant(options, description, model)
    if not options.emulate and plan.imu.source == "emulated":
        raise DeployError(
            f"{hardware}: [imu] source = \"emulated\" exists only on the actuator emulator: rehearse with --emulate, or set "
            "[imu] source to \"serial\" (an Xsens MTi: device, baudrate) or \"can\" (a CAN IMU's frames on a motor bus: bus, "
            "frames) for the robot (README, IMU)"
        )
    if options.rt_priority is not None:  # asked for real time: refused is an error before any bus opens, not a warning
        refused = probe_rt_priority(options.rt_priority)
        if refused is not None:
            raise DeployError(f"--rt-priority {options.rt_priority}: {refused}")
    loads = [str(load_) for load_ in plan.loads.values()]
    if dds:
        say(f"hardware {hardware}: {len(plan.motors)} joints over DDS (domain {plan.domain} on {plan.interface!r}) at {options.control_rate:g} Hz")
    else:
        say(f"hardware {hardware}: {len(plan.motors)} motors on {len(plan.buses)} buses at {options.control_rate:g} Hz")
    for line in loads:
        say(f"  {line}")

    sensors = _imu_profile(options)
    motor_faults, dds_faults = split_faults(options.faults, dds)
    host_faults = HostFaults(motor_faults)
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
            if plant is not None:
                say(f"emulated plant: {plant_label(plant)} (not the controller's model: {options.plant})")
            if sensors is not None and config.imu is None:
                config = replace(config, imu=sensors)
            if first_run is not None:
                config = with_gantry(config)
            if motor_faults:
                config = replace(config, faults=tuple(config.faults) + tuple(motor_faults))
            if dds:
                pass  # the DDS emulator starts with the robot (below, open_dds)
            elif options.emulator_mode == "process":
                rt = None if options.rt_priority is None else max(1, options.rt_priority - 1)  # just below the loop
                emulator = EmulatorProcess(plan, description, config, rt_priority=rt, plant=plant)  # built once, above
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
                # Unpaced (simulated time): no wall-clock deadline on the replies either (see the host's sends below).
                unpaced = {} if options.realtime else {"send_deadline": math.inf}
                emulator = ActuatorEmulator(truth, description, config, model=copy.copy(model) if model is not None and plant is None else None,
                                            plant=plant, **unpaced)  # fmt: skip
                host_plan, peer = on_channels(plan, emulator.host_plan()), emulator
                say("emulated actuators on python-can virtual buses (lockstep with the control loop"
                    + ("; replies read at the next cycle)" if options.reply_lag == 1 else ")"))
            if not dds:
                imu = imu_source_for(host_plan.imu, emulator.imu_channel)
        elif dds:
            host_plan, config = plan, None
        else:
            host_plan, peer = plan, None
            try:
                imu = imu_source_for(plan.imu)
            except (HardwareConfigError, ValueError) as error:
                raise DeployError(str(error)) from error
            if options.preflight:
                check_interfaces(plan, say)
        if dds:
            can_robot, emulator = open_dds(plan, description, options, config if options.emulate else None, dds_faults, say, plant=plant)
        elif plan.imu.source != "emulated":
            say(f"IMU: {plan.imu.source} ({host_plan.imu.device if plan.imu.source == 'serial' else 'bus ' + str(plan.imu.bus)}), "
                "read through its driver")  # fmt: skip
        estimator = None
        if wants_estimator(options, task_name) and description.floating_base:
            # The start-up holds the robot still anyway: a 4 s calibration window (16 blocks, not 0.75 s) averages the
            # gyro's noise to ~0.2 mrad/s per axis (the held robot's slow sway is read from the leg encoders).
            standstill = StandstillConfig(startup_blocks=16)
            estimator = StateEstimator(description, EstimatorConfig.for_sensors(sensors, standstill=standstill) if sensors is not None
                                       else EstimatorConfig(standstill=standstill))  # fmt: skip
        clock: list[Callable[[], float]] = []  # robot time for host-side faults (set once the robot exists)
        if isinstance(emulator, ActuatorEmulator):
            clock.append(lambda: emulator.time)  # lockstep: the emulator is at the cycle's time when the host sends
        links = None if dds else host_faults.links(host_plan, lambda: clock[0]() if clock else 0.0)
        if not dds:  # (the DDS robot is open: above)
            try:
                # Unpaced (lockstep, simulated time): no wall-clock budget on the sends. With one, a loaded
                # machine preempting the loop for > 5 ms mid-send dropped command frames, and the same
                # run ended clean or on a soft limit by the machine's load (measured: 26-98 frames dropped
                # per 10 s run beside 4 busy processes, none when idle).
                budget = {} if options.realtime else {"send_budget": math.inf}
                next_cycle = options.emulate and (options.emulator_mode == "process" or options.reply_lag == 1)  # replies read a cycle later
                can_robot = CanRobot(description, host_plan, imu=imu, peer=peer, reply_timeout=options.reply_timeout,
                                     wait_for_replies=not next_cycle, links=links, **budget)
            except Exception as error:  # noqa: BLE001 - python-can raises interface-specific errors
                raise DeployError(f"cannot open the CAN buses: {type(error).__name__}: {error}") from error
        if first_run is not None:
            can_robot.reduce_limits(first_run.torque_fraction, first_run.gain_fraction)
        robot = can_robot if estimator is None else EstimatedRobot(can_robot, estimator)

        if not clock:
            clock.append(lambda: robot.time() + 1.0 / options.control_rate)
        task = build_task(task_name, description, metadata, options)
        hold = walking_hold(task)
        recorders = () if hold is None else (WalkerRecorder(hold.walker),)  # the walker's state in the log, each tick
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
        }, extension=scene_channels(description, names, options.scene_rate, options.foxglove_port),
           channels=[r.channel for r in recorders])  # fmt: skip
        if options.foxglove_port is not None:
            say(f"Foxglove: open a connection to ws://{LIVE_HOST}:{options.foxglove_port} (the scene at 30 Hz, from the logger's process)")
        runtime = RealtimeRuntime(
            task, robot, agent_rate=agent_rate, controller_rate=options.control_rate, safety=safety,
            startup=options.startup, log=log, log_every=options.log_every, realtime=options.realtime,
            rt_priority=options.rt_priority, cpu_latency=options.cpu_latency, recorders=recorders,
        )  # fmt: skip
        if metadata is not None:
            check_layout(metadata, task)
        say(f"running {task_name} ({'walker' if task_name == 'walk' else options.controller}) for {options.seconds:g} s"
            + (" with the policy" if policy else ""))
        result = runtime.run(policy, options.seconds, progress=say)
        if options.rt_priority is not None or options.cpu_latency is not None:  # what was asked and what the kernel granted
            say(f"control loop: {runtime.scheduler}; CPUs' idle: {runtime.cpu_idle}")
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
    if hold is not None:
        walking = {"steps": hold.steps, "single_support_ticks": hold.single_support_ticks, "notes": list(hold.notes)}
        say(f"walking: {hold.steps} steps" + (f" (command: {'; '.join(hold.notes)})" if hold.notes else ""))
    say(f"log: {log.path}")
    if result.ok:
        message = "clean run: motors ramped to damping and switched off"
    elif result.fault is not None and result.fault.kind.value == "watchdog":
        unreachable = (runtime.emergency or {}).get("unreachable_buses") or []
        message = (f"stopped by a fault: {fault_summary(result.fault, plan)}; the watchdog switched the motors to damping then off"
                   + (f" (buses {', '.join(unreachable)} unreachable: their motors are left to their own timeout)" if unreachable else ""))
    else:
        message = f"stopped by a fault: {fault_summary(result.fault, plan)}; motors in damping then off"
        if result.unconfirmed_off:
            message += f" (not confirmed by {', '.join(result.unconfirmed_off)}: left to their own timeout)"
    if len(result.faults) > 1:
        message += "; also: " + ", ".join(f.kind.value for f in result.faults[1:])
    if result.ok:
        say(message)  # a fault's message is the caller's to print (once, on stderr)
    else:
        note = overload_note(options.emulate, result, load_average(), getattr(emulator, "stalls", None))
        if note:
            message += f". {note}"
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



__all__ = ["deploy", "scene_channels"]
