"""What ``giwbc deploy`` is asked (:class:`DeployOptions`) and what it reports
(:class:`DeployOutcome`): the input and the output of :func:`giwbc.apps.deploy_run.deploy`."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from giwbc.apps.deploy_walk import WalkCommand, non_finite
from giwbc.emulation import ActuatorEmulator, EmulatorConfig, FaultInjection
from giwbc.emulation.process import EmulatorProcess
from giwbc.errors import ConfigError
from giwbc.estimation.calibration import CalibrationReport
from giwbc.hal.safety import SafetyConfig
from giwbc.runtimes.phases import StartupConfig
from giwbc.runtimes.os_settings import RT_PRIORITY_RANGE, check_cpu_latency
from giwbc.runtimes.realtime import RunResult

EMULATOR_MODES = ("lockstep", "process")
TASKS = ("stand", "balance", "walk")
CONTROLLERS = ("wbc", "pd", "walk")
FIRST_RUN_CONTROLLER = "pd"  # on a gantry the feet carry nothing: a joint-level hold (giwbc.apps.deploy_setup.choose_task)


@dataclass(frozen=True)
class DeployOptions:
    """What ``giwbc deploy`` does (see :mod:`giwbc.apps.deploy_run`). Every number is checked when
    the options are built (:class:`~giwbc.errors.ConfigError` naming the field), so a bad value
    from Python stops before anything starts, as one from the command line does."""

    robot: str = "g1"
    policy: str | None = None
    task: str | None = None  # default: with a policy its own ("walk" for a G1Walk-v0 policy, else "balance"), "stand" without
    controller: str = None  # type: ignore[assignment]  # None: "pd" with first_run (a gantry), else "wbc"; a str once built
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
    transport: str = "can"  # "can": the plan's CAN buses; "dds": Unitree's low-level DDS interface (giwbc.apps.deploy_dds)
    release_service: bool = False  # dds: release the robot's locomotion service (motion switcher) before enabling motors
    restore_service: bool = False  # dds, with release_service: select the released mode again once the motors are off
    service_timeout: float = 5.0  # s the release (or the restore) may take before the run is refused
    # with emulate: the emulated robot's plant (giwbc.plants.resolve_plant: a shipped variant's name such as
    # "lagged_actuators", a variant .toml or an MJCF file of the same robot); None: the description's own model
    plant: str | None = None
    # with emulate: cycles from a command to the read of its replies. 0: the host waits for them in
    # the cycle (lockstep; what the CAN hardware path does); 1: read at the next cycle, one more
    # period of sense-to-act latency (what the process emulator does; with lockstep, the same
    # timing in the emulator's time, deterministic). None: the emulator mode's own (lockstep 0, process 1)
    reply_lag: int | None = None

    def __post_init__(self) -> None:
        if self.controller is None:
            object.__setattr__(self, "controller", FIRST_RUN_CONTROLLER if self.first_run else "wbc")
        _check_choice("controller", self.controller, CONTROLLERS)
        _check_choice("emulator_mode", self.emulator_mode, EMULATOR_MODES)
        _check_choice("transport", self.transport, ("can", "dds"))
        if (self.release_service or self.restore_service) and self.transport != "dds":
            raise ConfigError("--release-service / --restore-service hand the G1's locomotion service over DDS: they need --transport dds")
        if self.restore_service and not self.release_service:
            raise ConfigError("--restore-service selects the mode --release-service released: give both")
        _check_number("service_timeout", self.service_timeout, low=0.0, low_open=True, high=60.0, unit="s")
        if self.plant is not None:
            if not (isinstance(self.plant, str) and self.plant.strip()):
                raise ConfigError(f"plant must be a variant name or a .toml / MJCF path, got {self.plant!r}")
            if not self.emulate:
                raise ConfigError("--plant chooses the emulated robot's plant: it needs --emulate (on hardware the robot is the plant)")
        if self.reply_lag is not None:
            if self.reply_lag not in (0, 1) or isinstance(self.reply_lag, bool):
                raise ConfigError(f"reply_lag must be 0 or 1 cycles, got {self.reply_lag!r}")
            if not self.emulate or self.transport != "can":
                raise ConfigError("--reply-lag sets when the emulated CAN motors' replies are read: it needs --emulate (CAN)")
            if self.emulator_mode == "process" and self.reply_lag != 1:
                raise ConfigError("the emulator process answers on its own clock: its replies are read at the next cycle (--reply-lag 1)")
        if self.task is not None:
            _check_choice("task", self.task, TASKS)
        _check_number("seconds", self.seconds, low=0.0)
        _check_number("control_rate", self.control_rate, low=0.0, low_open=True, unit="Hz")
        _check_number("agent_rate", self.agent_rate, low=0.0, low_open=True, high=self.control_rate, unit="Hz")
        _check_number("reply_timeout", self.reply_timeout, low=0.0, low_open=True, high=1.0, unit="s")
        _check_number("scene_rate", self.scene_rate, low=0.0, high=self.control_rate, unit="Hz")
        if not (isinstance(self.log_every, int) and self.log_every >= 1):
            raise ConfigError(f"log_every must be an integer >= 1, got {self.log_every!r}")
        low, high = RT_PRIORITY_RANGE
        if self.rt_priority is not None and not (isinstance(self.rt_priority, int) and low <= self.rt_priority <= high):
            raise ConfigError(f"rt_priority must be a SCHED_FIFO priority from {low} to {high} (or None), got {self.rt_priority!r}")
        try:
            check_cpu_latency(self.cpu_latency)
        except ValueError as error:
            raise ConfigError(str(error)) from None
        for key, value in dict(self.walker or {}).items():
            bad = non_finite(value)
            if bad is not None:
                raise ConfigError(f"walker: {key} must be finite numbers, got {bad}")
        if self.foxglove_port is not None and not (isinstance(self.foxglove_port, int) and 1 <= self.foxglove_port <= 65535):
            raise ConfigError(f"foxglove_port must be a TCP port from 1 to 65535, got {self.foxglove_port!r}")


def _check_choice(name: str, value: Any, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ConfigError(f"{name} must be one of {', '.join(choices)}, got {value!r}")


def _check_number(
    name: str, value: Any, *, low: float | None = None, high: float | None = None, low_open: bool = False, unit: str = "s"
) -> None:
    """``value`` is a finite real number within [low, high] (``low_open``: > low); ConfigError naming ``name`` otherwise."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value <= high
    if not ok:
        bounds = " ".join(
            part for part in (f"{'>' if low_open else '>='} {low:g}" if low is not None else "", f"<= {high:g}" if high is not None else "") if part
        )
        raise ConfigError(f"{name} must be a finite number {bounds} {unit}, got {value!r}".replace("  ", " "))


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


__all__ = ["CONTROLLERS", "EMULATOR_MODES", "FIRST_RUN_CONTROLLER", "TASKS", "DeployOptions", "DeployOutcome"]
