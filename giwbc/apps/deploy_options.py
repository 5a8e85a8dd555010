"""What ``giwbc deploy`` is asked (:class:`DeployOptions`) and what it reports
(:class:`DeployOutcome`): the input and the output of :func:`giwbc.apps.deploy_run.deploy`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from giwbc.apps.deploy_walk import WalkCommand
from giwbc.emulation import ActuatorEmulator, EmulatorConfig, FaultInjection
from giwbc.emulation.process import EmulatorProcess
from giwbc.estimation.calibration import CalibrationReport
from giwbc.hal.safety import SafetyConfig
from giwbc.runtimes.phases import StartupConfig
from giwbc.runtimes.realtime import RunResult

EMULATOR_MODES = ("lockstep", "process")


@dataclass(frozen=True)
class DeployOptions:
    """What ``giwbc deploy`` does (see :mod:`giwbc.apps.deploy_run`)."""

    robot: str = "g1"
    policy: str | None = None
    task: str | None = None  # default: with a policy its own ("walk" for a G1Walk-v0 policy, else "balance"), "stand" without
    controller: str = "wbc"
    hardware: str | None = None  # default: the robot folder's hardware.toml
    emulate: bool = False
    emulator_mode: str = "lockstep"  # or "process": the emulator in its own process (giwbc.apps.deploy_run)
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
    cpu_latency: float | None = None  # hold the CPUs' wake-up latency at most this many µs while the motors are on (PM QoS; None: leave it)
    imu: str | None = None  # with emulate: "emulated", "serial" or "can" (the device the emulator imitates); None: the plan's
    preflight: bool = True  # SocketCAN pre-flight on real buses
    first_run: bool = False  # a robot on a gantry: reduced limits (FirstRunLimits)
    emulated_hardware: str | None = None  # with emulate: the emulated robot's true wiring (default: the plan), e.g. to rehearse a wrong sign
    scene_rate: float = 50.0  # Hz of the 3D scene (link transforms, contact forces) in the log; 0: none
    foxglove_port: int | None = None  # also stream the scene to Foxglove on this loopback port (the logger's process)
    imu_profile: str | None = None  # the IMU's class (giwbc.robot.noise.IMU_PROFILES): the emulated IMU's errors, the estimator's setup
    walk: WalkCommand | None = None  # the walk controller's command (None: stand)
    walker: Mapping[str, Any] | None = None  # the walk controller's WalkerConfig fields over the deployment walker's


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


__all__ = ["EMULATOR_MODES", "DeployOptions", "DeployOutcome"]
