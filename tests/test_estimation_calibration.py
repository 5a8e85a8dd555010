"""Start-up calibration, the gravity-only path, flat-foot tilt and the IMU profiles (issue #19).

The calibration tests replay a still G1 (a MuJoCo snapshot after the joint-PD hold settled,
repeated with fresh sensor noise) or the same snapshot moved on purpose, so "still" and "moving"
are exact; the closed-loop test runs the whole-body controller on the estimate of a MEMS IMU.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from giwbc.control.balance import BalanceOnEstimate
from giwbc.estimation.calibration import StandstillConfig
from giwbc.estimation.estimator import EstimatorConfig, Measurement, StateEstimator
from giwbc.estimation.evaluation import evaluate, push_sequence
from giwbc.estimation.orientation import OrientationFilter
from giwbc.robot import MujocoRobot, RobotDescription, so3
from giwbc.robot.interface import ImuReading
from giwbc.robot.noise import IMU_PROFILES, MIT_ENCODER_RESOLUTION, NoisyRobot, SensorNoiseConfig
from giwbc.robot.standing import PdHold

DT = 0.002
GYRO_NOISE = 0.011  # rad/s per sample (5e-4 rad/s/sqrt(Hz) at 500 Hz)
ACCEL_NOISE = 0.045  # m/s^2 per sample


@pytest.fixture(scope="module")
def snapshot(g1: RobotDescription):
    """A settled G1 under the joint-PD hold: true base rotation, joints, efforts."""
    sim = MujocoRobot(g1)
    hold = PdHold(g1)
    for _ in range(int(4.0 / DT)):
        hold(sim)
        sim.step()
    base = sim.base_state()
    return base.rotation.copy(), sim.joint_positions(), sim.joint_efforts(), sim.imu()


def _stream(g1, snapshot, rng, *, gyro_bias, accel_bias=np.zeros(3), seconds=1.0, rate=np.zeros(3), joint_wave=0.0,
            start=0.0, quantize=True):
    """Measurements of the snapshot (IMU without orientation output), with white noise, the given
    biases, the base turning at ``rate`` (rad/s, IMU frame) and leg joints waving by ``joint_wave`` rad."""
    rotation, positions, efforts, imu = snapshot
    imu_in_base = StateEstimator(g1).kinematics.imu_rotation
    imu_rotation = rotation @ imu_in_base
    for k in range(int(round(seconds / DT))):
        t = start + k * DT
        turned = imu_rotation @ so3.exp(rate * t)
        specific_force = turned.T @ np.array([0.0, 0.0, 9.81])
        joints = positions + joint_wave * math.sin(2 * math.pi * t) + 5e-4 * rng.standard_normal(len(positions))
        if quantize:
            joints = np.round(joints / MIT_ENCODER_RESOLUTION) * MIT_ENCODER_RESOLUTION
        reading = ImuReading(np.full(4, np.nan), rate + gyro_bias + GYRO_NOISE * rng.standard_normal(3),
                             specific_force + accel_bias + ACCEL_NOISE * rng.standard_normal(3), t)
        yield Measurement(reading, joints, 0.03 * rng.standard_normal(len(positions)), efforts + 0.5 * rng.standard_normal(len(efforts)))


def _estimator(g1) -> StateEstimator:
    return StateEstimator(g1, EstimatorConfig(use_imu_orientation=False))


def test_standstill_calibration_recovers_a_known_gyro_bias_within_10_percent_in_1_s(g1, snapshot) -> None:
    bias = np.array([0.03, -0.02, 0.025])  # rad/s: a cheap IMU's turn-on bias
    estimator = _estimator(g1)
    ready_at = None
    for measurement in _stream(g1, snapshot, np.random.default_rng(1), gyro_bias=bias, seconds=1.0):
        estimate = estimator.update(measurement)
        if estimate.ready and ready_at is None:
            ready_at = measurement.time
    assert ready_at is not None and ready_at <= 1.0
    report = estimator.calibration
    assert report is not None and report.tilt_source == "feet"
    assert np.linalg.norm(report.gyro_bias - bias) < 0.1 * np.linalg.norm(bias)
    assert np.linalg.norm(estimator.estimate.gyro_bias - bias) < 0.1 * np.linalg.norm(bias)
    assert "gyro bias" in report.summary()


@pytest.mark.parametrize(
    "motion",
    [{"rate": np.array([0.0, 0.05, 0.0])}, {"rate": np.array([0.04, 0.0, 0.0])}, {"joint_wave": 0.02}],
    ids=["pitching", "rolling", "legs-moving"],
)
def test_the_estimator_is_not_ready_while_the_robot_moves(g1, snapshot, motion) -> None:
    estimator = _estimator(g1)
    rng = np.random.default_rng(2)
    for measurement in _stream(g1, snapshot, rng, gyro_bias=np.full(3, 0.01), seconds=3.0, **motion):
        assert not estimator.update(measurement).ready
    assert estimator.calibration is None
    assert estimator.waiting_for.startswith("a standstill on both feet (")  # and what the detector last saw
    # The same estimator, once the robot stands still, calibrates within a second.
    for measurement in _stream(g1, snapshot, rng, gyro_bias=np.full(3, 0.01), seconds=1.0, start=3.0 + DT):
        estimator.update(measurement)
    assert estimator.ready


def test_a_slow_creep_over_a_long_start_up_window_is_not_taken_for_gyro_bias(g1, snapshot) -> None:
    """A 3 s start-up window while the base creeps in pitch at 0.002 rad/s with no joint moving
    (a robot rocking on its soles, below every "moving" threshold; without flat feet to read the
    turn from): the turn of the gravity direction over the window tells the creep from the bias,
    which is found to 0.0005 rad/s."""
    bias = np.array([0.004, -0.006, 0.008])
    creep = np.array([0.0, 0.002, 0.0])
    config = EstimatorConfig(use_imu_orientation=False, use_flat_feet=False, standstill=StandstillConfig(startup_blocks=12))
    estimator = StateEstimator(g1, config)
    for measurement in _stream(g1, snapshot, np.random.default_rng(5), gyro_bias=bias, rate=creep, seconds=3.6):
        estimator.update(measurement)
    report = estimator.calibration
    assert report is not None and report.window_duration >= 3.0
    assert np.abs(report.gyro_bias - bias).max() < 5e-4, report.gyro_bias  # the creep (2e-3) was not counted
    with pytest.raises(ValueError, match="startup_blocks must be >= 2"):
        StandstillConfig(startup_blocks=1)


def test_flat_feet_give_the_tilt_to_encoder_resolution_despite_a_60_mg_accelerometer_bias(g1, snapshot) -> None:
    accel_bias = np.array([0.6, -0.4, 0.2])  # ~60 mg: 3.5 degrees of tilt if gravity were trusted
    estimator = _estimator(g1)
    for measurement in _stream(g1, snapshot, np.random.default_rng(3), gyro_bias=np.zeros(3), accel_bias=accel_bias):
        estimator.update(measurement)
    report = estimator.calibration
    assert report is not None and report.tilt_source == "feet"
    true_up = snapshot[0][2]  # world z in the base frame: the third row of the base rotation
    estimated = so3.quat_to_matrix(estimator.estimate.base.quaternion)[2]
    error = math.acos(min(1.0, float(true_up @ estimated)))
    leg = len(estimator.kinematics.leg_joints(0))
    assert error <= leg * MIT_ENCODER_RESOLUTION  # each leg joint off by at most one quantization step
    assert report.accel_tilt_disagreement > math.radians(2.5)  # the accelerometer alone was far off
    np.testing.assert_allclose(report.accel_bias, accel_bias, atol=0.05)  # and its bias is calibrated


def test_gravity_only_path_converges_from_15_degrees_without_overshoot() -> None:
    tilted = so3.exp(np.array([0.0, math.radians(15.0), 0.0]))
    filt = OrientationFilter(accel_gain=0.5)
    filt.reset_to(so3.matrix_to_quat(tilted), np.zeros(3))  # starts 15 degrees off a level IMU
    rng = np.random.default_rng(4)
    pitch = []
    for _ in range(int(30.0 / DT)):
        filt.update(GYRO_NOISE * rng.standard_normal(3), DT, None, np.array([0.0, 0.0, 9.81]) + ACCEL_NOISE * rng.standard_normal(3))
        rotation = filt.rotation
        pitch.append(math.degrees(math.atan2(-rotation[2, 0], rotation[2, 2])))
    pitch = np.array(pitch)
    assert pitch.min() > -0.5  # never overshoots level by more than 0.5 degrees
    assert abs(pitch[-1]) < 0.1 and np.abs(pitch[-2500:]).max() < 0.2


def test_imu_profiles_are_what_their_datasheets_say() -> None:
    mems, cheap = SensorNoiseConfig.profile("mems"), SensorNoiseConfig.profile("cheap")
    assert not mems.orientation_output and SensorNoiseConfig.profile("ahrs").orientation_output
    assert mems.gyro_bias == pytest.approx(math.radians(0.5)) and mems.accel_bias == pytest.approx(0.020 * 9.80665)
    assert mems.imu_latency == 2 and mems.imu_dropout == pytest.approx(0.01)
    assert mems.encoder_resolution == pytest.approx(25.0 / 65535)
    assert cheap.gyro_bias == pytest.approx(math.radians(2.0)) and cheap.accel_bias == pytest.approx(0.060 * 9.80665)
    assert set(IMU_PROFILES) == {"ahrs", "mems", "cheap"}
    with pytest.raises(ValueError, match="unknown IMU profile"):
        SensorNoiseConfig.profile("perfect")


def test_sensor_model_applies_mounting_misalignment_and_reports_no_orientation_without_an_ahrs(g1) -> None:
    sim = MujocoRobot(g1)
    config = SensorNoiseConfig.ideal()
    from dataclasses import replace

    tilted = NoisyRobot(sim, replace(config, mounting_misalignment=math.radians(1.0), orientation_output=False),
                        np.random.default_rng(0))
    reading, truth = tilted.imu(), sim.imu()
    assert np.isnan(reading.quaternion).all()
    angle = math.acos(np.clip(reading.linear_acceleration @ truth.linear_acceleration
                              / (np.linalg.norm(reading.linear_acceleration) * np.linalg.norm(truth.linear_acceleration)), -1, 1))
    assert 0.1 < math.degrees(angle) < 4.0  # a 1-degree-per-axis mounting error turns the measured gravity


def test_wbc_on_a_mems_estimate_stands_through_pushes(g1: RobotDescription) -> None:
    noise = SensorNoiseConfig.profile("mems")
    result = evaluate(g1, noise=noise, seed=5, duration=8.0, pushes=push_sequence(8.0, lateral=60.0, sagittal=40.0),
                      controller=BalanceOnEstimate(g1))
    assert result.stood and result.ready_time_s < 3.0
    assert result.tilt_error_rms_deg < 0.5 and result.linear_velocity_error_rms_mps < 0.03 and result.height_drift_m < 0.005


def test_randomization_config_draws_an_imu_profile_per_episode(g1: RobotDescription) -> None:
    from giwbc.randomization import RandomizationConfig
    from giwbc.randomization.perturbed import sensor_errors
    from giwbc.randomization.sampling import sample_group

    config = RandomizationConfig.from_dict({"imu_profile": "cheap"}, g1)
    draws = [sensor_errors(sample_group(config, "episode", np.random.default_rng(seed))) for seed in range(200)]
    gyro = np.array([d.gyro_bias for d in draws])
    assert np.std(gyro) == pytest.approx(math.radians(2.0), rel=0.15)  # the datasheet's turn-on spread
    assert np.std([d.accel_bias for d in draws]) == pytest.approx(0.060 * 9.80665, rel=0.15)
    assert np.std([d.mounting for d in draws]) > 0 and all(d.imu_latency == 2 and d.imu_dropout == 0.02 for d in draws)
    assert draws[0].encoder_resolution == pytest.approx(MIT_ENCODER_RESOLUTION)


@pytest.mark.parametrize("use_flat_feet", [True, False], ids=["feet", "gravity"])
def test_without_an_orientation_output_the_calibration_keeps_the_configured_heading(g1, snapshot, use_flat_feet) -> None:
    """Nothing observes yaw without an orientation output: the calibrated base heads where the
    config says (``initial_yaw``), with the tilt from the feet or from gravity, and its tilt is the
    true one."""
    estimator = StateEstimator(g1, EstimatorConfig(use_imu_orientation=False, use_flat_feet=use_flat_feet, initial_yaw=0.8))
    for measurement in _stream(g1, snapshot, np.random.default_rng(3), gyro_bias=np.zeros(3), seconds=1.0):
        estimate = estimator.update(measurement)
    assert estimate.ready and estimator.calibration.tilt_source == ("feet" if use_flat_feet else "gravity")
    rotation = estimate.base.rotation
    assert math.atan2(rotation[1, 0], rotation[0, 0]) == pytest.approx(0.8, abs=0.02)
    truth = snapshot[0]
    assert math.acos(np.clip(rotation[2] @ truth[2], -1.0, 1.0)) < math.radians(0.5)  # the vertical in the base frame: the tilt


# --- what the standstill detector watches, large biases, the orientation output's heading ------------
def _heading(rotation: np.ndarray) -> float:
    return math.atan2(rotation[1, 0], rotation[0, 0])


def _moved(stream, change):
    """``stream`` with each measurement passed through ``change(t, measurement)``."""
    for measurement in stream:
        yield change(measurement.time, measurement)


@pytest.mark.parametrize("joint, watched", [("right_knee_joint", True), ("left_shoulder_pitch_joint", False)])
def test_the_standstill_detector_watches_every_leg_joint_and_only_those(g1, snapshot, joint, watched) -> None:
    """A knee waving by 0.02 rad keeps the estimator from calibrating (the legs are what tells a
    standstill); an arm waving does not (the base stays still on the feet)."""
    index = g1.joint_names.index(joint)
    wave = np.zeros(g1.dofs)
    wave[index] = 0.02

    def waving(t, m):
        return replace(m, joint_positions=m.joint_positions + wave * math.sin(2 * math.pi * t))

    estimator = _estimator(g1)
    for measurement in _moved(_stream(g1, snapshot, np.random.default_rng(4), gyro_bias=np.full(3, 0.01), seconds=2.0), waving):
        estimator.update(measurement)
    assert estimator.ready is not watched


def test_a_gyro_bias_of_11_degrees_per_second_is_learnt_whole(g1, snapshot) -> None:
    """Up to ``max_gyro_bias`` (20 deg/s) the calibrated bias is not clipped: a 0.2 rad/s turn-on
    bias (a poor MEMS gyro after a shock) is removed from the angular velocity."""
    bias = np.array([0.2, -0.15, 0.25])
    estimator = _estimator(g1)
    for measurement in _stream(g1, snapshot, np.random.default_rng(6), gyro_bias=bias, seconds=1.0):
        estimate = estimator.update(measurement)
    assert estimate.ready
    np.testing.assert_allclose(estimate.gyro_bias, bias, atol=0.01)
    np.testing.assert_allclose(estimate.base.angular_velocity, np.zeros(3), atol=0.05)  # the base is still


def _with_output(g1, stream, imu_rotation: np.ndarray):
    """``stream`` with an orientation output: the IMU's orientation ``imu_rotation`` (world)."""
    quaternion = so3.matrix_to_quat(imu_rotation)
    for m in stream:
        yield replace(m, imu=replace(m.imu, quaternion=quaternion.copy()))


def _turned_snapshot(g1, snapshot, heading: float, pitch: float):
    """The snapshot with its base pitched by ``pitch`` (the robot on a slope) and heading exactly ``heading``."""
    rotation, positions, efforts, imu = snapshot
    tilted = so3.exp(np.array([0.0, pitch, 0.0])) @ rotation
    turned = so3.exp(np.array([0.0, 0.0, heading - _heading(tilted)])) @ tilted
    return (turned, positions, efforts, imu)


@pytest.mark.parametrize("heading, pitch, output_pitch", [(math.pi, 0.0, math.radians(1.0)), (2.3, math.radians(20.0), 0.0)],
                         ids=["half-turn", "on-a-20-degree-slope"])
def test_the_calibrated_heading_is_the_orientation_outputs(g1, snapshot, heading, pitch, output_pitch) -> None:
    """With an orientation output (and gravity for the tilt), the calibrated base heads where the
    output says: also at exactly +-pi, and on a slope, where the base's x axis is far from
    horizontal. An output pitched 1 degree off gravity is reported as a 1-degree offset."""
    turned = _turned_snapshot(g1, snapshot, heading, pitch)
    imu_in_base = StateEstimator(g1).kinematics.imu_rotation
    output = so3.exp(np.array([0.0, output_pitch, 0.0])) @ turned[0] @ imu_in_base  # world-frame pitch: same heading
    estimator = StateEstimator(g1, EstimatorConfig(use_flat_feet=False))
    stream = _stream(g1, turned, np.random.default_rng(7), gyro_bias=np.zeros(3), seconds=1.0)
    for measurement in _with_output(g1, stream, output):
        estimate = estimator.update(measurement)
    assert estimate.ready
    error = math.remainder(_heading(estimate.base.rotation) - heading, 2 * math.pi)
    assert abs(error) < 1e-3, error
    truth = turned[0]
    assert math.acos(np.clip(estimate.base.rotation[2] @ truth[2], -1.0, 1.0)) < math.radians(0.2)  # the output's offset removed
    report = estimator.calibration
    assert report.orientation_output_offset == pytest.approx(output_pitch, abs=math.radians(0.1))
    assert report.pitch == pytest.approx(-math.asin(truth[2, 0]), abs=math.radians(0.2))
    assert report.roll == pytest.approx(math.atan2(truth[2, 1], truth[2, 2]), abs=math.radians(0.2))


def test_the_initial_height_puts_the_stance_sole_on_the_ground(g1, snapshot) -> None:
    """Started with the left foot lifted (contact plan: right foot only), the estimated base puts
    the right sole on the ground (height 0) and the left one above it."""
    _, positions, _, _ = snapshot
    lifted = positions.copy()
    names = g1.joint_names
    for joint, angle in (("left_hip_pitch_joint", -0.3), ("left_knee_joint", 0.6), ("left_ankle_pitch_joint", -0.3)):
        lifted[names.index(joint)] += angle
    measurement = next(_stream(g1, snapshot, np.random.default_rng(8), gyro_bias=np.zeros(3), quantize=False))
    estimator = StateEstimator(g1, EstimatorConfig(use_imu_orientation=False, calibrate=False))
    estimate = estimator.update(replace(measurement, joint_positions=lifted), np.array([False, True]))
    model = g1.build_pinocchio()
    data = model.createData()
    pin.framesForwardKinematics(model, data, estimate.q)
    heights = []
    for contact in g1.contacts:
        placement = data.oMf[model.getFrameId(contact.link)]
        heights.append(float((placement.translation + placement.rotation @ np.asarray(contact.center, float))[2]))
    assert heights[1] == pytest.approx(0.0, abs=1e-9) and heights[0] > 0.05, heights


def test_gravity_alone_relevels_a_tilt_the_gyro_made_up_and_says_when_it_had_no_reference(g1, snapshot) -> None:
    """Gravity-only (no orientation output, feet not used), with a 0.5 m/s^2 accelerometer bias
    along the vertical: a gyro glitch after calibration (0.5 rad/s about x for 0.1 s that the base
    never did) tilts the estimate by ~3 degrees; only gravity can bring it back, within 2 s. A
    sample without a usable accelerometer has no reference ("none"), and the gyro alone carries it."""
    estimator = StateEstimator(g1, EstimatorConfig(use_imu_orientation=False, use_flat_feet=False, gravity_gain=4.0))
    assert estimator.reference == "none"
    truth = snapshot[0]

    def glitch(t, m):
        if 1.2 <= t < 1.3:
            return replace(m, imu=replace(m.imu, angular_velocity=m.imu.angular_velocity + np.array([0.5, 0.0, 0.0])))
        return m

    def tilt_error() -> float:
        return math.degrees(math.acos(np.clip(estimator.estimate.base.rotation[2] @ truth[2], -1.0, 1.0)))

    errors = {}
    stream = _stream(g1, snapshot, np.random.default_rng(9), gyro_bias=np.zeros(3), accel_bias=np.array([0.0, 0.0, 0.5]), seconds=3.3)
    for measurement in _moved(stream, glitch):
        estimator.update(measurement)
        if measurement.time in (1.0, 1.3, 3.3 - DT):
            errors[measurement.time] = tilt_error()
    assert estimator.ready and estimator.reference == "gravity"
    assert not estimator.flat_feet.any()  # the feet are not used: none is counted flat
    assert errors[1.0] < 0.5 and errors[1.3] > 2.0 and errors[3.3 - DT] < 0.5, errors
    last = measurement
    nan = replace(last, imu=replace(last.imu, linear_acceleration=np.full(3, np.nan), time=last.time + DT))
    estimator.update(nan)
    assert estimator.reference == "none"
    assert tilt_error() < 0.5


def test_the_soles_are_averaged_and_a_leg_with_a_bad_encoder_is_not_counted_flat(g1, snapshot) -> None:
    """One ankle encoder reading 2 degrees off (the left foot seems pitched): the two flat soles
    disagree and the estimated tilt is off by half of it, before and long after the calibration.
    A non-finite encoder on the left leg: that foot is not counted flat, the right one still is."""
    offset = np.zeros(g1.dofs)
    offset[g1.joint_names.index("left_ankle_pitch_joint")] = math.radians(2.0)
    estimator = _estimator(g1)
    truth = snapshot[0]
    stream = _stream(g1, snapshot, np.random.default_rng(10), gyro_bias=np.zeros(3), seconds=4.0)
    errors = []
    for measurement in _moved(stream, lambda t, m: replace(m, joint_positions=m.joint_positions + offset)):
        estimate = estimator.update(measurement)
        if measurement.time in (1.0, 4.0 - DT):
            errors.append(math.degrees(math.acos(np.clip(estimate.base.rotation[2] @ truth[2], -1.0, 1.0))))
    assert estimate.ready and estimator.flat_feet.tolist() == [True, True]
    assert len(errors) == 2 and all(0.8 < e < 1.2 for e in errors), errors
    bad = measurement.joint_positions.copy()
    bad[g1.joint_names.index("left_knee_joint")] = np.nan
    estimator.update(replace(measurement, joint_positions=bad, imu=replace(measurement.imu, time=measurement.time + DT)))
    assert estimator.flat_feet.tolist() == [False, True]


def _edge_couple(g1, snapshot) -> np.ndarray:
    """Joint efforts of a pure pitch couple on the left sole that moves its centre of pressure by
    about one sole half length (to its toe or heel edge)."""
    rotation, positions, _, _ = snapshot
    model = g1.build_pinocchio()
    data = model.createData()
    q = np.concatenate([[0.0, 0.0, 0.8], so3.matrix_to_quat(rotation), positions])
    pin.computeJointJacobians(model, data, q)
    pin.framesForwardKinematics(model, data, q)
    foot = g1.contacts[0]
    jacobian = pin.getFrameJacobian(model, data, model.getFrameId(foot.link), pin.LOCAL_WORLD_ALIGNED)
    couple = np.array([0.0, 1.0, 0.0]) * foot.half_length * g1.total_mass * 9.81 / 2  # CoP ~ one half length off
    return jacobian[3:, 6:].T @ couple


def test_a_foot_loaded_on_its_toe_edge_is_not_counted_flat(g1, snapshot) -> None:
    """The left leg's efforts carry an extra pitch couple that puts the centre of pressure at the
    sole's edge (a foot rolling on its toe or heel, whose tilt says nothing about the ground): it is
    no longer counted flat; with the couple gone it is again."""
    extra = _edge_couple(g1, snapshot)
    estimator = _estimator(g1)
    flat = []
    stream = _stream(g1, snapshot, np.random.default_rng(11), gyro_bias=np.zeros(3), seconds=1.4)
    for k, measurement in enumerate(stream):
        if 500 <= k < 600:  # 1.0 s to 1.2 s
            measurement = replace(measurement, joint_efforts=measurement.joint_efforts + extra)
        estimator.update(measurement)
        if k in (499, 599, 699):
            flat.append(estimator.flat_feet.tolist())
    assert flat == [[True, True], [False, True], [True, True]]


def test_the_held_heading_splits_a_disagreement_between_the_soles(g1, snapshot) -> None:
    """After calibration the left hip-yaw encoder drifts by 2 degrees over 2 s (slower than a foot
    slip): the left sole seems to turn, the right one does not; the flat feet hold the heading
    at their mean, so the estimated heading moves by half the drift."""
    joint = g1.joint_names.index("left_hip_yaw_joint")

    def drifting(t, m):
        positions = m.joint_positions.copy()
        positions[joint] += math.radians(2.0) * min(1.0, max(0.0, (t - 1.2) / 2.0))
        return replace(m, joint_positions=positions)

    estimator = _estimator(g1)
    headings = []
    stream = _stream(g1, snapshot, np.random.default_rng(12), gyro_bias=np.zeros(3), seconds=5.0)
    for k, measurement in enumerate(_moved(stream, drifting)):
        estimate = estimator.update(measurement)
        if k in (600, 2499):  # 1.2 s (calibrated, before the drift) and 5 s
            headings.append(_heading(estimate.base.rotation))
    assert estimate.ready and estimator.foot_twists == 0
    turned = abs(math.degrees(headings[1] - headings[0]))
    assert 0.8 < turned < 1.2, turned


def test_a_slow_creep_on_the_edge_of_a_sole_is_not_taken_for_gyro_bias(g1, snapshot) -> None:
    """The slow-creep start-up (0.002 rad/s in pitch, no joint moving) with flat feet in use but the
    left foot loaded on its edge: the soles cannot say how the base turned, the gravity direction
    can, and the bias is found to 0.0005 rad/s."""
    bias = np.array([0.004, -0.006, 0.008])
    extra = _edge_couple(g1, snapshot)
    config = EstimatorConfig(use_imu_orientation=False, standstill=StandstillConfig(startup_blocks=12))
    estimator = StateEstimator(g1, config)
    stream = _stream(g1, snapshot, np.random.default_rng(5), gyro_bias=bias, rate=np.array([0.0, 0.002, 0.0]), seconds=3.6)
    for measurement in _moved(stream, lambda t, m: replace(m, joint_efforts=m.joint_efforts + extra)):
        estimator.update(measurement)
    report = estimator.calibration
    assert report is not None and report.tilt_source == "gravity" and report.window_duration >= 3.0
    assert np.abs(report.gyro_bias - bias).max() < 5e-4, report.gyro_bias


def test_the_config_for_an_imu_without_an_ahrs_starts_from_gravity_at_the_configured_heading(g1, snapshot) -> None:
    """``EstimatorConfig.for_sensors``: an IMU without an orientation output is not asked for one;
    the first sample then starts the estimate level on gravity, heading ``initial_yaw``."""
    assert EstimatorConfig.for_sensors(SensorNoiseConfig()).use_imu_orientation
    config = EstimatorConfig.for_sensors(SensorNoiseConfig(orientation_output=False), calibrate=False, initial_yaw=0.8)
    assert not config.use_imu_orientation and not config.calibrate
    first = next(_stream(g1, snapshot, np.random.default_rng(13), gyro_bias=np.zeros(3), quantize=False))
    estimate = StateEstimator(g1, config).update(first)
    assert _heading(estimate.base.rotation) == pytest.approx(0.8, abs=0.01)
    assert math.acos(np.clip(estimate.base.rotation[2] @ snapshot[0][2], -1.0, 1.0)) < math.radians(1.0)


def test_feet_measured_on_a_known_raised_ground_lift_the_estimate(g1, snapshot) -> None:
    """Started with the ground guessed at 0 but told the feet stand on a 10 cm platform
    (``ground_height``): within 2 s the estimated base is 10 cm higher than with the guess alone."""
    heights = {}
    for name, ground in (("guess", None), ("platform", 0.1)):
        estimator = StateEstimator(g1, EstimatorConfig(use_imu_orientation=False, calibrate=False, ground_height=ground))
        for measurement in _stream(g1, snapshot, np.random.default_rng(14), gyro_bias=np.zeros(3), seconds=2.0):
            estimate = estimator.update(measurement)
        heights[name] = estimate.base.position[2]
    assert heights["platform"] - heights["guess"] == pytest.approx(0.1, abs=0.005), heights



def test_later_standstills_relearn_an_accelerometer_bias_that_shifted(g1, snapshot) -> None:
    """After calibration the accelerometer's bias shifts by 0.1 g along z (a temperature step) on a
    still robot on flat feet: the zero-velocity updates of later standstills learn it, so the
    estimated height does not creep (under 0.5 mm from 3 s to 6 s; kept, the shift makes it climb
    ~0.5 mm/s) and the mean vertical velocity of the last second is under 1.5 mm/s."""
    shift = np.array([0.0, 0.0, 0.1 * 9.81])

    def shifted(t, m):
        return replace(m, imu=replace(m.imu, linear_acceleration=m.imu.linear_acceleration + shift)) if t >= 1.2 else m

    estimator = _estimator(g1)
    heights, velocities = {}, []
    for k, measurement in enumerate(_moved(_stream(g1, snapshot, np.random.default_rng(15), gyro_bias=np.zeros(3), seconds=6.0), shifted)):
        estimate = estimator.update(measurement)
        if k in (1500, 2999):
            heights[k] = estimate.base.position[2]
        if k >= 2500:
            velocities.append(estimate.base.linear_velocity[2])
    assert estimate.ready and estimator.zero_velocity_updates >= 5
    assert abs(heights[2999] - heights[1500]) < 5e-4, heights
    assert abs(np.mean(velocities)) < 1.5e-3, np.mean(velocities)


def test_flat_feet_pull_a_tilt_error_back_at_the_feet_gain(g1, snapshot) -> None:
    """A gyro glitch after calibration (0.5 rad/s in pitch for 0.1 s, never done by the base)
    tilts the estimate by ~2.6 degrees; the flat feet pull it back at ``feet_gain`` (2/s): over the
    next 0.5 s the error shrinks by about e^-1 (between 0.25 and 0.42 of it), neither slower nor faster."""

    def glitch(t, m):
        if 1.2 <= t < 1.3:
            return replace(m, imu=replace(m.imu, angular_velocity=m.imu.angular_velocity + np.array([0.0, 0.5, 0.0])))
        return m

    estimator = _estimator(g1)
    errors = {}
    for k, measurement in enumerate(_moved(_stream(g1, snapshot, np.random.default_rng(16), gyro_bias=np.zeros(3), seconds=1.8), glitch)):
        estimate = estimator.update(measurement)
        if k in (649, 899):  # the glitch's end (1.3 s) and 0.5 s later
            errors[k] = math.degrees(math.acos(np.clip(estimate.base.rotation[2] @ snapshot[0][2], -1.0, 1.0)))
    assert estimator.reference == "feet" and errors[649] > 2.0, errors
    assert 0.25 < errors[899] / errors[649] < 0.42, errors
