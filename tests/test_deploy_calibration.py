"""``giwbc deploy --emulate --imu-profile mems``: the start-up calibration of the state estimator on
the emulated MEMS IMU (gyro + accelerometer only), in simulated (unpaced, lockstep) time: it waits
for a detected standstill after the ramp, finds the injected gyro bias, logs and reports what it
found, and only then hands the estimate to the WBC, which stands on it; a robot that never stands
still ends in a clear start-up fault instead."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from giwbc.apps.deploy import DeployOptions, deploy
from giwbc.emulation import EmulatorConfig, FaultInjection
from giwbc.hal.safety import FaultKind, SafetyConfig
from giwbc.robot.noise import SensorNoiseConfig
from giwbc.runlog import read_log
from giwbc.runtimes.phases import StartupConfig

ROOT = Path(__file__).resolve().parents[1]
STARTUP = StartupConfig(settle_time=0.05, ramp_time=0.5, shutdown_time=0.3, off_delay=0.1)


@pytest.fixture(scope="module")
def model(g1):
    return g1.build_mujoco()


def _options(tmp_path, **overrides) -> DeployOptions:
    base = dict(emulate=True, realtime=False, controller="wbc", seconds=2.0, log=str(tmp_path / "run.mcap"), imu_profile="mems",
                startup=STARTUP, reply_timeout=0.05, safety=SafetyConfig(max_stall=1.0))  # fmt: skip
    base.update(overrides)
    return DeployOptions(**base)


def test_deploy_calibrates_the_mems_imu_then_the_wbc_stands_on_the_estimate(g1, model, tmp_path) -> None:
    # The mems profile's errors, its gyro bias held constant (no random walk) so that "the injected
    # bias" is one number to compare with.
    imu = SensorNoiseConfig.profile("mems", gyro_bias_random_walk=0.0)
    lines: list[str] = []
    outcome = deploy(_options(tmp_path, emulator=EmulatorConfig(imu=imu)), model=model, description=g1, out=lines.append)
    assert outcome.exit_code == 0, outcome.message
    injected = outcome.emulator.imu_errors.gyro_bias
    assert np.linalg.norm(injected) > 0.5 * imu.gyro_bias  # a bias worth finding (0.45 deg/s here)
    calibration = outcome.calibration
    assert calibration is not None and calibration.tilt_source == "feet"
    assert np.linalg.norm(calibration.gyro_bias - injected) < 0.1 * np.linalg.norm(injected), (calibration.gyro_bias, injected)
    assert outcome.standing["stood"] and outcome.standing["seconds"] >= 1.9
    assert any(line.startswith("IMU calibrated at t=") for line in lines)

    log = read_log(outcome.log_path)
    phases = [e["detail"]["phase"] for e in log.events if e["event"] == "phase"]
    assert phases == ["enable", "settle", "ramp", "calibrate", "running", "shutdown", "damping", "off"]
    (logged,) = [e["detail"] for e in log.events if e["event"] == "calibration"]
    np.testing.assert_allclose(logged["gyro_bias"], calibration.gyro_bias)
    times = outcome.result.phase_times
    # Not assumed: a standstill window (4 s; its first block may hold the ramp's still end) ended by
    # the calibration, the controller after it.
    assert times["calibrate"] - 0.25 <= calibration.time - calibration.window_duration
    assert calibration.window_duration >= 4.0 and calibration.time <= times["running"]
    assert not [m for m in log.topic("/commands") if m["phase"] == "calibrate" and max(m["kp"]) == 0.0]  # the PD hold, no WBC
    # The estimator ran on the emulated IMU: no orientation output; its estimate tracks the base.
    assert np.isnan(log.array("/estimator", "imu_quaternion")).all()
    estimate, est_t = log.array("/estimator", "position"), log.array("/estimator", "t")
    truth = outcome.emulator.truth_between(times["running"], times["shutdown"])
    assert np.abs(np.interp(truth[:, 0], est_t, estimate[:, 2]) - truth[:, 1]).max() < 0.03


def test_a_robot_that_never_stands_still_is_not_handed_to_the_controller(g1, model, tmp_path) -> None:
    """A lateral force on the pelvis that keeps changing (the robot rocks): no standstill window,
    no calibration: after the timeout a start-up fault that says what the estimator waited for,
    and the controller never ran."""
    rocking = tuple(
        FaultInjection("push", force=(0.0, 40.0 * (-1) ** k, 0.0), start=0.6 + 0.15 * k, stop=0.6 + 0.15 * (k + 1)) for k in range(20)
    )
    startup = StartupConfig(settle_time=0.05, ramp_time=0.5, shutdown_time=0.3, off_delay=0.1, calibration_timeout=2.0)
    outcome = deploy(_options(tmp_path, startup=startup, faults=rocking, seconds=1.0), model=model, description=g1, out=None)
    assert outcome.exit_code == 1 and outcome.calibration is None
    fault = outcome.result.fault
    assert fault.kind is FaultKind.STARTUP and "did not calibrate within 2 s" in fault.message
    assert "still waiting for a standstill on both feet" in fault.message
    assert "running" not in outcome.result.phase_times


def test_the_walking_policy_sees_gravity_from_the_estimate_on_an_imu_without_orientation(g1, model, tmp_path) -> None:
    """A MEMS IMU reports no orientation (a NaN quaternion): the policy's gravity observation comes
    from the calibrated estimate (EstimatedRobot.imu), so its first action is finite (it was NaN,
    the run stopped by ``nonfinite_policy`` at the hand-over) and it walks on the estimate."""
    from giwbc.apps.deploy import load_policy
    from giwbc.apps.deploy_walk import WalkCommand

    policy, metadata = load_policy(str(ROOT / "policies" / "g1_walk_residual.onnx"))
    gravity: list[np.ndarray] = []

    def observed(observation: np.ndarray) -> np.ndarray:
        gravity.append(np.asarray(observation[:3], float).copy())  # gravity_imu/x, y, z: the observation's first three
        return policy(observation)

    options = _options(tmp_path, seconds=1.0, walk=WalkCommand(vx=0.3), scene_rate=0.0)
    outcome = deploy(options, policy=observed, policy_metadata=metadata, model=model, description=g1, out=None)
    assert outcome.exit_code == 0, outcome.message
    assert len(gravity) >= 40 and np.isfinite(gravity).all()
    # standing up: gravity points down the IMU's (nearly base-aligned) z axis, within a few degrees
    tilt = np.degrees(np.arccos(np.clip(-np.array(gravity)[:, 2] / np.linalg.norm(gravity, axis=1), -1, 1)))
    assert tilt.max() < 8.0, tilt.max()
    assert outcome.standing["stood"]
