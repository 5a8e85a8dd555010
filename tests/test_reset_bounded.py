"""env.reset() with the estimator in the loop ends in bounded time at every WBC rate the envs accept:
the start-up calibration's gantry damper acts at every physics step (stable whatever the control
period), and its timeout counts its own simulated time, not MuJoCo's clock (which restarts when a
state diverges)."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from giwbc.envs.factories import g1_walk
from giwbc.errors import EstimatorCalibrationError

AHRS = {"imu_profile": "ahrs", "parameters": []}
WALL_LIMIT_S = 60  # far above a reset's ~1 s; a hang would otherwise stall the suite forever


@pytest.fixture(scope="module")
def g1_model(g1):
    return g1.build_mujoco()


@contextmanager
def bounded(seconds: int) -> Iterator[None]:
    """Fail (instead of hanging) when the block runs past ``seconds`` of wall time."""

    def expire(*_: object) -> None:
        raise TimeoutError(f"did not return within {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def make(g1, g1_model, rate: float, estimator: object = True):
    """G1Walk as the shipped walking policy trains it: estimator in the loop, AHRS IMU errors."""
    return g1_walk(robot=g1, model=g1_model, controller_rate=rate, walker="deployment", initial_joint_noise=0.0,
                   sim2real={"estimator": estimator}, randomization=AHRS)


@pytest.mark.parametrize("rate", [100.0, 250.0, 500.0])
def test_reset_calibrates_and_stands_at_every_wbc_rate(g1, g1_model, rate):
    env = make(g1, g1_model, rate)
    for seed in (0, 1):
        with bounded(WALL_LIMIT_S):
            env.reset(seed=seed)
        truth = env.engine_robot.base_state()
        calibrated = env.sim_robot.tick * env.rates.physics_dt
        assert 0.5 < calibrated < env.estimator.calibration_timeout  # a standstill window (>= 0.75 s) took place
        assert env.estimated.estimator.ready
        assert truth.position[2] > 0.7  # standing: pelvis at its standing height (0.78 m), not fallen
        assert truth.rotation[2, 2] > np.cos(np.radians(3.0))  # upright within 3 deg
        assert np.linalg.norm(truth.linear_velocity) < 0.02 and np.linalg.norm(truth.angular_velocity) < 0.05  # still


def test_a_diverging_calibration_raises_instead_of_hanging(g1, g1_model):
    """A gantry damper far too stiff for the physics step blows the state up: MuJoCo restarts its
    clock at every divergence, yet the calibration gives up after its own timeout."""
    env = make(g1, g1_model, 250.0, estimator={"calibration_timeout": 1.0, "gantry_damping": (1e7, 1e6)})
    with bounded(WALL_LIMIT_S), pytest.raises(EstimatorCalibrationError, match="did not calibrate within 1 s"):
        env.reset(seed=0)
    assert env.sim_robot.tick == round(1.0 / env.rates.physics_dt)  # exactly its own 1 s of physics steps
    assert env.engine_robot.time() < 1.0  # ... while MuJoCo's clock restarted at the divergence
