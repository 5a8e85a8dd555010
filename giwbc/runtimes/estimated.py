"""The state estimator in a simulated runtime's loop: the task sees the base the way a deployed one does.

With ``sim2real={"estimator": ...}`` a :class:`~giwbc.runtimes.simulated.SimulatedRuntime` binds its
task to an :class:`~giwbc.estimation.estimated_robot.EstimatedRobot` over the simulated robot: the
base state, link poses and contact forces the task and its controller read come from a
:class:`~giwbc.estimation.estimator.StateEstimator` fed with the robot's *measured* IMU, encoders
and joint efforts (their errors: the randomizer's sensor entries, e.g. ``{"imu_profile": "mems"}``,
drawn per episode), as on ``giwbc deploy``. Reward, termination and info keep reading the simulated
truth (:attr:`giwbc.tasks.task.Task.truth`).

Each reset then runs the estimator's start-up calibration as ``giwbc deploy`` does (its ``calibrate``
phase, :mod:`giwbc.runtimes.phases`): the joints held by PD at the description's default pose with
its gains, the estimator updated every control tick, until it has seen a standstill on both feet and
restarted from it (gyro and accelerometer biases, tilt). The episode starts there: the robot's clock
does not start at 0, and pushes count from the end of the calibration. Without an IMU bias the
estimator would not need it; with a datasheet bias (0.3 deg/s) an uncalibrated estimate walks the G1
over within seconds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Any

import numpy as np

from giwbc.errors import EstimatorCalibrationError
from giwbc.estimation.estimated_robot import EstimatedRobot
from giwbc.estimation.estimator import ANY_FEET, EstimatorConfig, StateEstimator
from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import ImpedanceCommand, Robot

__all__ = ["EstimatorInLoop", "calibrate"]


@dataclass(frozen=True)
class EstimatorInLoop:
    """How a simulated runtime runs the state estimator in its loop (module doc).

    ``startup_blocks``: the calibration's standstill window in 0.25-s blocks (``giwbc deploy``
    takes 16, 4 s, to average the gyro's noise; fewer cost less simulated time per episode and
    leave a larger gyro-bias error, ~0.6 mrad/s per axis at 3 blocks for a 0.5 mrad/s/sqrt(Hz)
    gyro); ``calibration_timeout``: simulated seconds of holding still before giving up (counted
    in the calibration's own physics steps: bounded whatever the engine's clock does);
    ``gantry_damping``: ``(N s/m, N m s)`` of a damper on the base while the robot is held, applied
    at every physics step whatever the controller rate (:func:`calibrate`; ``(0, 0)``: the joints'
    PD alone, which takes several seconds to settle);
    ``config``: :class:`EstimatorConfig` fields over the defaults and :data:`ANY_FEET` (feet that
    are not the description's flat box, flat ground: the simulated floor is); ``joint_rate``: the
    standstill's largest leg-joint creep rate (rad/s): a robot held on a soft floor creeps by
    several mrad while the floor settles; the calibration's tilt comes from the window's gravity and
    encoders, and a creep of 0.01 rad/s moves the IMU at ~7 mm/s, whose change over a 1-s window
    tilts the mean gravity by under 0.05 deg.
    """

    startup_blocks: int = 4
    calibration_timeout: float = 5.0
    joint_rate: float = 0.01
    gantry_damping: tuple[float, float] = (600.0, 60.0)
    config: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    def __post_init__(self) -> None:
        if isinstance(self.startup_blocks, bool) or not isinstance(self.startup_blocks, int) or self.startup_blocks < 2:
            raise ValueError(f"estimator startup_blocks must be an int >= 2, got {self.startup_blocks!r}")
        if not (0 < self.calibration_timeout < math.inf):
            raise ValueError(f"estimator calibration_timeout must be a positive number of seconds, got {self.calibration_timeout!r}")
        if not (0 <= self.joint_rate < math.inf):
            raise ValueError(f"estimator joint_rate must be a finite rate >= 0 (rad/s), got {self.joint_rate!r}")
        if len(self.gantry_damping) != 2 or not all(0 <= float(d) < math.inf for d in self.gantry_damping):
            raise ValueError(f"estimator gantry_damping must be two finite values >= 0 (N s/m, N m s), got {self.gantry_damping!r}")
        object.__setattr__(self, "gantry_damping", (float(self.gantry_damping[0]), float(self.gantry_damping[1])))
        known = {f.name for f in fields(EstimatorConfig)}
        unknown = sorted(set(self.config) - known)
        if unknown:
            raise ValueError(f"estimator config: unknown EstimatorConfig fields {unknown}; known: {sorted(known)}")
        if "calibrate" in self.config and not self.config["calibrate"]:
            raise ValueError("estimator config: calibrate=False would start from uncalibrated IMU biases; the runtime calibrates")
        object.__setattr__(self, "config", MappingProxyType(dict(self.config)))

    @classmethod
    def from_value(cls, value: "EstimatorInLoop | Mapping[str, Any] | bool | None") -> "EstimatorInLoop | None":
        """``True``: the defaults; a mapping: the fields; ``None``/``False``: no estimator."""
        if value is None or value is False:
            return None
        if value is True:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, Mapping):
            return cls(**dict(value))
        raise ValueError(f"sim2real estimator must be true, a mapping of EstimatorInLoop fields or null, got {value!r}")

    def estimator(self, description: RobotDescription) -> StateEstimator:
        """A fresh estimator of ``description`` with this configuration."""
        config = replace(EstimatorConfig(), **{**ANY_FEET, **dict(self.config)})
        standstill = replace(config.standstill, startup_blocks=self.startup_blocks, joint_rate=self.joint_rate)
        return StateEstimator(description, replace(config, standstill=standstill, calibrate=True))

    def wrap(self, robot: Robot, description: RobotDescription) -> EstimatedRobot:
        """``robot`` (the simulated robot, its sensors perturbed or not) seen through a new estimator."""
        return EstimatedRobot(robot, self.estimator(description))


def calibrate(
    estimated: EstimatedRobot, description: RobotDescription, physics_per_controller: int, timeout: float,
    damping: tuple[float, float] = (0.0, 0.0),
) -> float:
    """Reset the estimator and hold the joints by PD at the default pose, stepping the simulation
    one control period at a time, until the estimator is ready. Returns the simulated seconds it
    took; :class:`EstimatorCalibrationError` after ``timeout`` s (the robot did not stand still).

    ``damping``: ``(N s/m, N m s)`` of a gantry's damper on the base (a world-frame wrench against
    the true base velocity, zero at rest, so the feet carry the weight): the PD-held G1 rocks
    for seconds before it is still enough to calibrate on; damped, it settles within about one.
    The damper is re-evaluated at every physics step, as a physical damper acts: held over a
    whole control period (2 or more physics steps below 500 Hz) its explicit update overshoots
    on the light pelvis and diverges. The timeout counts the physics steps taken here, not the
    engine's clock (which MuJoCo restarts when a state diverges), so the wait is bounded."""
    robot = estimated.robot
    estimator = estimated.estimator
    estimator.reset()
    estimated.set_contact_plan(None)  # the last episode's plan (one foot, if it ended mid-step) would unload a foot
    hold = ImpedanceCommand(description.default_positions.copy(), np.zeros(description.dofs), description.kp.copy(),
                            description.kd.copy(), np.zeros(description.dofs))
    linear, angular = damping
    gantry = linear > 0 or angular > 0
    dt = description.timestep
    steps, limit = 0, math.ceil(timeout / dt - 1e-9)  # physics steps taken, and the most allowed
    robot.set_joint_impedance(hold)  # held: the backend evaluates it at every physics step (Robot.set_joint_impedance)
    estimated.update()
    try:
        while not estimator.ready:
            if steps >= limit:
                raise EstimatorCalibrationError(
                    f"the state estimator did not calibrate within {timeout:g} s of simulated standing: waiting for "
                    f"{estimator.waiting_for}. A robot reset with its joints off the default pose creeps for seconds while "
                    "held there: start it at the default pose (e.g. G1Walk(initial_joint_noise=0)), or raise calibration_timeout"
                )
            if gantry:
                for _ in range(physics_per_controller):
                    base = robot.base_state()  # the simulation's truth: the gantry is part of the world, not of the robot
                    robot.set_external_wrench(description.base_link, -linear * base.linear_velocity,  # type: ignore[attr-defined]
                                              -angular * base.angular_velocity)
                    robot.step(1)  # type: ignore[attr-defined]
            else:
                robot.step(physics_per_controller)  # type: ignore[attr-defined]
            steps += physics_per_controller
            estimated.update()
    finally:
        if gantry:
            robot.set_external_wrench(description.base_link, np.zeros(3), np.zeros(3))  # type: ignore[attr-defined]
    return steps * dt
