"""NoisyRobot: seeded noise, bias, latency, saturation and dropout on what a real robot measures,
and no base state (a real robot has none to report)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.errors import ConfigError, NonFiniteCommand

from giwbc.robot.interface import BaseState, ContactWrench, ImpedanceCommand, ImuReading, Robot
from giwbc.robot.noise import NoisyRobot, NotMeasuredError, SensorErrors, SensorModel, SensorNoiseConfig

DOFS = 4


class ScriptedRobot(Robot):
    """A robot whose true readings are set by the test: a deterministic function of the step."""

    def __init__(self) -> None:
        self.step_count = 0
        self.dt = 0.002
        self.torques: np.ndarray | None = None
        self.impedance: ImpedanceCommand | None = None
        self.gyro_override: np.ndarray | None = None

    def step(self, n: int = 1) -> None:
        self.step_count += n

    @property
    def name(self) -> str:
        return "scripted"

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(f"j{i}" for i in range(DOFS))

    @property
    def floating_base(self) -> bool:
        return True

    def time(self) -> float:
        return self.step_count * self.dt

    def joint_positions(self) -> np.ndarray:
        return np.full(DOFS, 0.1 * self.step_count)

    def joint_velocities(self) -> np.ndarray:
        return np.full(DOFS, 0.5)

    def joint_efforts(self) -> np.ndarray:
        return np.arange(DOFS, dtype=float)

    def base_state(self) -> BaseState:
        return BaseState(np.array([0.0, 0.0, 0.7]), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3))

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(3), np.eye(3)

    def contact_wrench(self, link: str) -> ContactWrench:
        return ContactWrench(np.zeros(3), np.zeros(3), True)

    def imu(self) -> ImuReading:
        gyro = np.array([0.01 * self.step_count, 0.0, 0.0]) if self.gyro_override is None else self.gyro_override
        return ImuReading(np.array([0.0, 0.0, 0.0, 1.0]), gyro, np.array([0.0, 0.0, 9.81]), self.time())

    def _send_joint_torques(self, torques: np.ndarray) -> None:
        self.torques = torques

    def set_joint_impedance(self, command: ImpedanceCommand) -> None:
        self.impedance = command


def record(config: SensorNoiseConfig, seed: int, steps: int = 50) -> np.ndarray:
    """Every measured channel, one row per step."""
    truth = ScriptedRobot()
    noisy = NoisyRobot(truth, config, np.random.default_rng(seed))
    rows = []
    for _ in range(steps):
        imu = noisy.imu()
        rows.append(np.concatenate([imu.quaternion, imu.angular_velocity, imu.linear_acceleration, [imu.time],
                                    noisy.joint_positions(), noisy.joint_velocities(), noisy.joint_efforts()]))
        truth.step()
    return np.array(rows)


def test_same_seed_gives_identical_noise_and_another_seed_does_not() -> None:
    config = SensorNoiseConfig()
    first, second, other = record(config, 7), record(config, 7), record(config, 8)
    np.testing.assert_array_equal(first, second)
    assert not np.allclose(first, other)


def test_ideal_sensors_report_the_truth_immediately() -> None:
    truth = ScriptedRobot()
    noisy = NoisyRobot(truth, SensorNoiseConfig.ideal(), np.random.default_rng(0))
    truth.step(3)
    np.testing.assert_array_equal(noisy.joint_positions(), truth.joint_positions())
    np.testing.assert_array_equal(noisy.joint_efforts(), truth.joint_efforts())
    np.testing.assert_array_equal(noisy.imu().angular_velocity, truth.imu().angular_velocity)
    assert noisy.imu().time == truth.time()


def test_latency_delays_each_channel_by_its_number_of_samples() -> None:
    config = SensorNoiseConfig.ideal()
    config = SensorNoiseConfig(**{**config.as_dict(), "imu_latency": 2, "joint_latency": 1})
    truth = ScriptedRobot()
    noisy = NoisyRobot(truth, config, np.random.default_rng(0))
    for _ in range(5):
        noisy.imu()
        truth.step()
    # Now at step 5: the IMU shows step 3 (with its own timestamp), the joints step 4.
    imu = noisy.imu()
    assert imu.time == pytest.approx(3 * truth.dt)
    assert imu.angular_velocity[0] == pytest.approx(0.03)
    np.testing.assert_allclose(noisy.joint_positions(), 0.4)
    assert noisy.time() == pytest.approx(5 * truth.dt)


def test_white_noise_matches_its_density_and_bias_is_constant_per_robot() -> None:
    config = SensorNoiseConfig(gyro_bias_random_walk=0.0, accel_bias_random_walk=0.0, imu_latency=0, joint_latency=0)
    rows = record(config, seed=3, steps=3000)  # the scripted gyro ramps to 30 rad/s, inside the range
    truth_gyro = 0.01 * np.arange(3000)
    gyro_error = rows[:, 4] - truth_gyro
    expected_std = config.gyro_noise_density / math.sqrt(config.sample_period)
    assert np.std(gyro_error) == pytest.approx(expected_std, rel=0.1)
    accel_error = rows[:, 7:10] - [0.0, 0.0, 9.81]
    bias = accel_error.mean(axis=0)
    assert np.all(np.abs(bias) < 5 * config.accel_bias)  # a turn-on bias of the configured size...
    assert np.linalg.norm(bias) > 1e-3  # ... that is there
    joint_velocity_error = rows[:, 11 + DOFS : 11 + 2 * DOFS] - 0.5
    assert np.std(joint_velocity_error) == pytest.approx(config.joint_velocity_noise, rel=0.1)


def test_imu_orientation_noise_keeps_a_unit_quaternion_near_the_truth() -> None:
    rows = record(SensorNoiseConfig(orientation_noise=0.01), seed=1, steps=200)
    np.testing.assert_allclose(np.linalg.norm(rows[:, :4], axis=1), 1.0, atol=1e-12)
    angles = 2 * np.arccos(np.clip(np.abs(rows[:, 3]), 0, 1))
    assert 0.005 < np.sqrt(np.mean(angles**2)) < 0.05


def test_saturation_clips_at_the_sensor_range() -> None:
    truth = ScriptedRobot()
    config = SensorNoiseConfig(gyro_range=10.0, imu_latency=0)
    noisy = NoisyRobot(truth, config, np.random.default_rng(0))
    truth.gyro_override = np.array([50.0, -50.0, 0.0])
    gyro = noisy.imu().angular_velocity
    assert gyro[0] == 10.0 and gyro[1] == -10.0


def test_encoder_resolution_quantizes_positions() -> None:
    config = SensorNoiseConfig(encoder_resolution=0.01, joint_position_noise=0.003, joint_latency=0)
    rows = record(config, seed=0, steps=20)
    positions = rows[:, 11 : 11 + DOFS]
    np.testing.assert_allclose(positions / 0.01, np.round(positions / 0.01), atol=1e-9)


def test_dropout_repeats_the_last_imu_sample_with_its_timestamp() -> None:
    rows = record(SensorNoiseConfig(imu_dropout=0.5, imu_latency=0), seed=2, steps=100)
    times = rows[:, 10]
    repeats = np.flatnonzero(np.diff(times) == 0.0)
    assert 20 < len(repeats) < 80
    np.testing.assert_array_equal(rows[repeats + 1, :10], rows[repeats, :10])


def test_base_state_links_and_contacts_are_not_measured_but_truth_stays_reachable() -> None:
    truth = ScriptedRobot()
    noisy = NoisyRobot(truth, SensorNoiseConfig(), np.random.default_rng(0))
    reads = (noisy.base_state, noisy.generalized_state, lambda: noisy.link_pose("pelvis"), lambda: noisy.contact_wrench("foot"))
    for read in reads:
        with pytest.raises(NotMeasuredError):
            read()
    with pytest.raises(NotMeasuredError, match="estimat"):
        noisy.base_state()
    assert noisy.robot is truth
    assert noisy.robot.base_state().position[2] == 0.7
    assert noisy.joint_names == truth.joint_names and noisy.floating_base


def test_commands_pass_through_unchanged() -> None:
    truth = ScriptedRobot()
    noisy = NoisyRobot(truth, SensorNoiseConfig(), np.random.default_rng(0))
    torques = np.array([1.0, 2.0, 3.0, 4.0])
    noisy.set_joint_torques(torques)
    np.testing.assert_array_equal(truth.torques, torques)
    command = ImpedanceCommand.damping(DOFS, 1.0)
    noisy.set_joint_impedance(command)
    assert truth.impedance is command


def test_wrappers_check_commands_once_and_unwrap() -> None:
    """Bad torques stop at the outermost wrapper with the hierarchy's errors; nothing reaches the robot."""
    truth = ScriptedRobot()
    noisy = NoisyRobot(truth, SensorNoiseConfig(), np.random.default_rng(0))
    outer = NoisyRobot(noisy, SensorNoiseConfig(), np.random.default_rng(1))
    assert outer.robot is noisy and outer.unwrapped is truth and noisy.unwrapped is truth
    truth.torques = None
    with pytest.raises(NonFiniteCommand, match="not finite"):
        outer.set_joint_torques(np.array([1.0, np.nan, 0.0, 0.0]))
    with pytest.raises(ConfigError, match=f"expected {DOFS} joint torques"):
        outer.set_joint_torques(np.zeros(DOFS + 1))
    assert truth.torques is None
    with pytest.raises(TypeError, match="wraps a Robot"):
        NoisyRobot(object(), SensorNoiseConfig(), np.random.default_rng(0))  # type: ignore[arg-type]


def test_time_going_backwards_restarts_the_latency_buffer() -> None:
    truth = ScriptedRobot()
    noisy = NoisyRobot(truth, SensorNoiseConfig(imu_latency=3), np.random.default_rng(0))
    for _ in range(10):
        noisy.imu()
        truth.step()
    truth.step_count = 0  # the simulation was reset
    assert noisy.imu().time == 0.0


def test_invalid_configs_are_rejected() -> None:
    with pytest.raises(ValueError, match="gyro_noise_density"):
        SensorNoiseConfig(gyro_noise_density=-1.0)
    with pytest.raises(ValueError, match="integer"):
        SensorNoiseConfig(imu_latency=1.5)
    with pytest.raises(ValueError, match="probability"):
        SensorNoiseConfig(imu_dropout=1.0)
    with pytest.raises(ValueError, match="Generator"):
        NoisyRobot(ScriptedRobot(), SensorNoiseConfig())


def test_one_sensor_model_takes_per_joint_errors_too() -> None:
    """The model NoisyRobot uses is the one PerturbedRobot builds from a randomization sample:
    per-joint noise and bias, no error at all when ideal."""
    assert SensorErrors().is_ideal() and SensorNoiseConfig.ideal().errors(np.random.default_rng(0)).is_ideal()
    assert not SensorNoiseConfig().errors(np.random.default_rng(0)).is_ideal()
    truth = ScriptedRobot()
    std, bias = np.array([0.0, 0.01, 0.02, 0.0]), np.array([0.1, 0.0, -0.1, 0.0])
    model = SensorModel(truth, SensorErrors(joint_position_noise=std, joint_position_bias=bias), np.random.default_rng(4), imu=False)
    errors = []
    for _ in range(2000):
        errors.append(model.joint_positions() - truth.joint_positions())
        truth.step()
    np.testing.assert_allclose(np.mean(errors, axis=0), bias, atol=2e-3)
    np.testing.assert_allclose(np.std(errors, axis=0), std, rtol=0.1, atol=1e-12)
    np.testing.assert_array_equal(model.imu().angular_velocity, truth.imu().angular_velocity)  # imu=False: the robot's own


def _reference_measure_imu(errors: SensorErrors, gyro_bias: np.ndarray, accel_bias: np.ndarray, truth: ImuReading,
                           elapsed: float, draws: np.ndarray, jitter: float) -> tuple[ImuReading, np.ndarray, np.ndarray]:
    """The IMU model as first written on numpy arrays (before it moved to Python floats): the reference."""
    from giwbc.robot.so3 import exp, matrix_to_quat, quat_multiply

    e, walk = errors, math.sqrt(max(elapsed, 0.0))
    mounting = exp(np.broadcast_to(np.asarray(e.mounting, float), (3,)))
    truth = ImuReading(quat_multiply(truth.quaternion, matrix_to_quat(mounting)), mounting.T @ truth.angular_velocity,
                       mounting.T @ truth.linear_acceleration, truth.time)
    gyro_bias = gyro_bias + e.gyro_bias_walk * walk * draws[3:6]
    accel_bias = accel_bias + e.accel_bias_walk * walk * draws[9:12]
    gyro = np.minimum(np.maximum(truth.angular_velocity + gyro_bias + e.gyro_noise * draws[0:3], -e.gyro_range), e.gyro_range)
    accel = np.minimum(np.maximum(truth.linear_acceleration + accel_bias + e.accel_noise * draws[6:9], -e.accel_range), e.accel_range)
    error = np.asarray(e.orientation_bias, float).copy()
    error[2] += e.heading_drift * float(truth.time)
    quaternion = quat_multiply(matrix_to_quat(exp(error)), truth.quaternion)
    rotation_vector = e.orientation_noise * draws[12:15]
    angle = float(np.linalg.norm(rotation_vector))
    delta = np.concatenate([math.sin(0.5 * angle) / angle * rotation_vector, [math.cos(0.5 * angle)]])
    return ImuReading(quat_multiply(quaternion, delta), gyro, accel, truth.time + jitter), gyro_bias, accel_bias


def test_the_imu_model_on_floats_matches_its_numpy_reference(rng) -> None:
    """Every IMU error on (mounting, orientation tilt and heading drift, noise, bias walks, saturation):
    the per-sample model computes what its numpy reference does, to rounding, on random truths."""
    errors = SensorErrors(gyro_noise=0.02, gyro_bias=np.array([0.01, -0.02, 0.005]), gyro_bias_walk=1e-3, accel_noise=0.05,
                          accel_bias=np.array([0.1, 0.0, -0.2]), accel_bias_walk=1e-2, orientation_noise=0.01,
                          orientation_bias=np.array([0.004, -0.006, 0.0]), heading_drift=2e-3, mounting=np.array([0.003, -0.002, 0.004]),
                          gyro_range=3.0, accel_range=40.0)
    model = SensorModel(ScriptedRobot(), errors, np.random.default_rng(0))
    gyro_bias, accel_bias = model.gyro_bias, model.accel_bias
    for _ in range(200):
        quaternion = rng.standard_normal(4)
        truth = ImuReading(quaternion / np.linalg.norm(quaternion), 2.0 * rng.standard_normal(3), 15.0 * rng.standard_normal(3),
                           float(rng.uniform(0.0, 100.0)))
        draws, elapsed, jitter = rng.standard_normal(15), float(rng.uniform(0.0, 0.01)), float(rng.uniform(-1e-4, 1e-4))
        expected, gyro_bias, accel_bias = _reference_measure_imu(errors, gyro_bias, accel_bias, truth, elapsed, draws, jitter)
        got = model._measure_imu(truth, elapsed, draws.tolist(), jitter)
        for name in ("quaternion", "angular_velocity", "linear_acceleration"):
            np.testing.assert_allclose(getattr(got, name), getattr(expected, name), rtol=0, atol=1e-13, err_msg=name)
        assert got.time == expected.time
        np.testing.assert_allclose(model.gyro_bias, gyro_bias, rtol=0, atol=1e-15)
        np.testing.assert_allclose(model.accel_bias, accel_bias, rtol=0, atol=1e-15)
    assert np.abs(got.angular_velocity).max() <= 3.0 and np.abs(got.linear_acceleration).max() <= 40.0
