"""Evaluate the estimator in MuJoCo against ground truth: standing with pushes, sensor noise on.

:func:`evaluate` runs the scenario the acceptance criteria name (G1 standing for 20 s, pushed on
the pelvis every few seconds), feeding the estimator only what a :class:`NoisyRobot` measures and
comparing its output with the simulator's truth. The controller is pluggable: the joint-PD hold
by default, or any callable that closes its loop on the estimate (the whole-body controller).
Until the estimator is ``ready`` (its start-up standstill calibration) the joint-PD hold stands
the robot, unpushed, as a deployment's settle phase would; the scenario (``duration`` s, pushes
timed from then) and its scoring start when it is ready.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace

import mujoco
import numpy as np

from giwbc.robot.description import RobotDescription
from giwbc.estimation.estimator import Estimate, EstimatorConfig, Measurement, StateEstimator
from giwbc.robot.interface import Robot
from giwbc.robot.mujoco_robot import MujocoRobot
from giwbc.robot.noise import NoisyRobot, SensorNoiseConfig
from giwbc.robot.standing import PdHold

__all__ = ["Controller", "EvaluationResult", "Push", "evaluate", "push_sequence"]

# A controller: reads the measured robot and the estimate, writes the robot's commands.
Controller = Callable[[Robot, Estimate], None]


@dataclass(frozen=True)
class Push:
    """A world-frame force on a link (at its centre of mass) from ``start`` for ``duration`` s."""

    start: float
    duration: float
    force: tuple[float, float, float]
    link: str = "pelvis"

    def active(self, t: float) -> bool:
        return self.start <= t < self.start + self.duration


def push_sequence(
    duration: float = 20.0,
    first: float = 1.0,
    period: float = 2.5,
    push_duration: float = 0.2,
    lateral: float = 50.0,
    sagittal: float = 20.0,
    link: str = "pelvis",
) -> tuple[Push, ...]:
    """Pushes every ``period`` s, cycling left, forward, right, backward (lateral = +-y,
    sagittal = +-x). The defaults are what the joint-PD hold survives in sequence: alone it takes
    one 60 N lateral or 30 N sagittal push, but its sagittal rocking mode is barely damped and
    60 N lateral pushes slide the feet inward, so repeated 60/30 N pushes topple it within 20 s;
    50 N lateral and 20 N sagittal stay under 6 degrees of tilt for push periods of 2-3 s.
    A balance controller should take 40-60 N both ways."""
    forces = [(0.0, lateral, 0.0), (sagittal, 0.0, 0.0), (0.0, -lateral, 0.0), (-sagittal, 0.0, 0.0)]
    starts = np.arange(first, duration - push_duration, period)
    return tuple(Push(float(s), push_duration, forces[i % 4], link) for i, s in enumerate(starts))


@dataclass(frozen=True)
class EvaluationResult:
    """Estimator errors against truth over one run, and what the run did."""

    duration_s: float
    updates: int
    orientation_error_rms_deg: float
    tilt_error_rms_deg: float  # roll/pitch only: the angle between true and estimated base z axes
    linear_velocity_error_rms_mps: float  # norm of the world-frame base velocity error
    height_drift_m: float  # max |height error - initial height error|
    height_error_max_m: float  # max |height error|
    horizontal_drift_m: float  # max |xy error - initial xy error|
    angular_velocity_error_rms: float
    contact_agreement: float  # fraction of samples whose contact flags match the touch sensors
    update_median_us: float
    update_p99_us: float
    faults: int
    fault_counts: dict[str, int]  # the kinds that occurred
    stood: bool
    max_tilt_deg: float
    pushes: int
    ready_time_s: float = float("nan")  # when the estimator became ready (nan: never; then scored throughout)
    heading_drift_deg_per_min: float = 0.0  # max |heading error - its value at ready| over the scored time, per minute
    heading_error_final_deg: float = 0.0
    calibration: dict | None = None  # the estimator's calibration report
    # With evaluate(traces=True): the errors against time since ready (for plots), else None.
    traces: dict[str, np.ndarray] | None = field(default=None, repr=False, compare=False)

    def as_dict(self) -> dict[str, object]:
        return {k: v for k, v in asdict(self).items() if k != "traces"}


def evaluate(
    description: RobotDescription,
    *,
    noise: SensorNoiseConfig | None = None,
    seed: int = 0,
    duration: float = 20.0,
    pushes: Sequence[Push] | None = None,
    controller: Controller | None = None,
    config: EstimatorConfig | None = None,
    mujoco_model: mujoco.MjModel | None = None,
    calibration_timeout: float = 5.0,
    traces: bool = False,
) -> EvaluationResult:
    """Run ``duration`` s of standing with ``pushes`` (default :func:`push_sequence`), estimating
    at every physics step from noisy measurements, and compare with truth. The estimator's
    world frame is aligned with the simulator's by ``initial_base_xy`` and ``initial_yaw`` (the
    truth at start); ``config`` defaults to :meth:`EstimatorConfig.for_sensors` of ``noise``.
    ``mujoco_model``: a compiled model of ``description`` to reuse (compiling takes ~1 s).
    The scenario starts when the estimator is ready; an estimator not ready after
    ``calibration_timeout`` s runs it anyway (``ready_time_s`` nan) and is scored throughout.
    ``traces``: also keep the tilt, velocity and height errors against time (``EvaluationResult.traces``)."""
    sim = MujocoRobot(description, mujoco_model)
    noise = noise if noise is not None else SensorNoiseConfig()
    robot = NoisyRobot(sim, noise, np.random.default_rng(seed))
    start = sim.base_state()
    start_xy = tuple(float(x) for x in start.position[:2])
    start_yaw = float(np.arctan2(start.rotation[1, 0], start.rotation[0, 0]))
    config = config if config is not None else EstimatorConfig.for_sensors(noise)
    estimator = StateEstimator(description, replace(config, initial_base_xy=start_xy, initial_yaw=start_yaw))
    hold = PdHold(description)
    controller = controller if controller is not None else hold
    pushes = tuple(push_sequence(duration) if pushes is None else pushes)
    touch = [f"{c.name}_touch" for c in description.contacts]
    steps = int(round((duration + calibration_timeout) / description.timestep))
    true_q, est_q = np.empty((steps, 4)), np.empty((steps, 4))
    true_p, est_p = np.empty((steps, 3)), np.empty((steps, 3))
    true_v, est_v = np.empty((steps, 3)), np.empty((steps, 3))
    true_w, est_w = np.empty((steps, 3)), np.empty((steps, 3))
    agree = np.empty(steps, dtype=bool)
    ready = np.empty(steps, dtype=bool)
    timings = np.empty(steps)
    started: float | None = None  # when the scenario started (the estimator was ready)
    k = 0
    for k in range(steps):
        now = sim.time()
        if started is None and now >= calibration_timeout:
            started = now
        if started is not None:
            if now - started >= duration - 0.5 * description.timestep:
                break
            _apply_pushes(sim, pushes, now - started)
        measurement = Measurement.from_robot(robot)
        start = time.perf_counter()
        estimate = estimator.update(measurement)
        timings[k] = time.perf_counter() - start
        ready[k] = estimate.ready
        if started is None and estimate.ready:
            started = now
        (controller if estimate.ready else hold)(robot, estimate)
        truth = sim.base_state()
        true_p[k], true_q[k] = truth.position, truth.quaternion
        true_v[k], true_w[k] = truth.linear_velocity, truth.angular_velocity
        base = estimate.base
        est_p[k], est_q[k], est_v[k], est_w[k] = base.position, base.quaternion, base.linear_velocity, base.angular_velocity
        agree[k] = np.array_equal(estimate.contacts, [sim.sensor(name)[0] > 0.0 for name in touch])
        sim.step()
    else:
        k = steps
    true_q, est_q, true_p, est_p, true_v, est_v = true_q[:k], est_q[:k], true_p[:k], est_p[:k], true_v[:k], est_v[:k]
    true_w, est_w, agree, ready, timings = true_w[:k], est_w[:k], agree[:k], ready[:k], timings[:k]
    tilt = np.degrees(np.arccos(np.clip(1.0 - 2.0 * (true_q[:, 0] ** 2 + true_q[:, 1] ** 2), -1.0, 1.0)))
    stood = bool(tilt.max() < 20.0 and true_p[:, 2].min() > 0.5 * true_p[0, 2])
    first = int(np.argmax(ready)) if ready.any() else 0
    ready_time = first * description.timestep if ready.any() else float("nan")
    true_q, est_q, true_p, est_p = true_q[first:], est_q[first:], true_p[first:], est_p[first:]
    true_v, est_v, true_w, est_w, agree, timings = true_v[first:], est_v[first:], true_w[first:], est_w[first:], agree[first:], timings[first:]
    heading_error = np.degrees(np.angle(np.exp(1j * (_yaw(est_q) - _yaw(true_q)))))
    heading_drift = np.abs(np.degrees(np.angle(np.exp(1j * np.radians(heading_error - heading_error[0])))))
    scored_minutes = max(len(heading_error) * description.timestep / 60.0, 1e-9)
    cos_half = np.clip(np.abs(np.sum(true_q * est_q, axis=1)), 0.0, 1.0)
    orientation_error = np.degrees(2.0 * np.arccos(cos_half))
    tilt_error = np.degrees(np.arccos(np.clip(np.sum(_z_axis(true_q) * _z_axis(est_q), axis=1), -1.0, 1.0)))
    position_error = est_p - true_p
    return EvaluationResult(
        duration_s=duration,
        updates=len(timings),
        orientation_error_rms_deg=_rms(orientation_error),
        tilt_error_rms_deg=_rms(tilt_error),
        linear_velocity_error_rms_mps=_rms(np.linalg.norm(est_v - true_v, axis=1)),
        height_drift_m=float(np.max(np.abs(position_error[:, 2] - position_error[0, 2]))),
        height_error_max_m=float(np.max(np.abs(position_error[:, 2]))),
        horizontal_drift_m=float(np.max(np.linalg.norm(position_error[:, :2] - position_error[0, :2], axis=1))),
        angular_velocity_error_rms=_rms(np.linalg.norm(est_w - true_w, axis=1)),
        contact_agreement=float(np.mean(agree)),
        update_median_us=float(np.median(timings) * 1e6),
        update_p99_us=float(np.percentile(timings, 99) * 1e6),
        faults=estimator.monitor.total,
        fault_counts={name: count for name, count in estimator.fault_counts.items() if count},
        stood=stood,
        max_tilt_deg=float(tilt.max()),
        pushes=len(pushes),
        ready_time_s=ready_time,
        heading_drift_deg_per_min=float(heading_drift.max() / scored_minutes),
        heading_error_final_deg=float(heading_error[-1]),
        calibration=None if estimator.calibration is None else estimator.calibration.as_dict(),
        traces=None if not traces else {
            "t": np.arange(len(tilt_error)) * description.timestep, "tilt_error_deg": tilt_error,
            "velocity_error_mps": np.linalg.norm(est_v - true_v, axis=1), "height_error_m": position_error[:, 2],
        },
    )


def _apply_pushes(sim: MujocoRobot, pushes: Sequence[Push], now: float) -> None:
    forces: dict[str, np.ndarray] = {push.link: np.zeros(3) for push in pushes}
    for push in pushes:
        if push.active(now):
            forces[push.link] += push.force
    for link, force in forces.items():
        sim.set_external_wrench(link, force)


def _z_axis(quaternions: np.ndarray) -> np.ndarray:
    """Third column of the rotation matrices of quaternions (N, 4) ``(x, y, z, w)``."""
    x, y, z, w = quaternions.T
    return np.stack([2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)], axis=1)


def _yaw(quaternions: np.ndarray) -> np.ndarray:
    """Heading of quaternions (N, 4) ``(x, y, z, w)``: the angle of their x axis in the ground plane."""
    x, y, z, w = quaternions.T
    return np.arctan2(2 * (x * y + z * w), 1 - 2 * (y * y + z * z))


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))
