"""The state estimator's compiled kernels (issue 37, :mod:`giwbc.estimation.kernels`) against what they
replace: Pinocchio's own kinematics and dynamics, a textbook Kalman filter over the full state, and each
kernel's uncompiled Python function on random inputs; the whole estimator compiled against uncompiled
over a closed-loop walk; compiling without any writable cache folder."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium
import numpy as np
import pinocchio as pin
import pytest

import giwbc.envs
from giwbc.estimation import kernels
from giwbc.estimation.estimator import Measurement, StateEstimator
from giwbc.policy import OnnxPolicy
from giwbc.robot.interface import ImuReading
from giwbc.util.shipped import shipped_policy
from giwbc.estimation.kalman import LegKalmanFilter, LegKalmanNoise
from giwbc.estimation.kinematics import LegKinematics
from giwbc.robot.description import RobotDescription

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def _run_leg_kinematics(kernel, model: pin.Model, frames: list[int], q: np.ndarray, v: np.ndarray, a: np.ndarray,
                        efforts: np.ndarray, legs: np.ndarray | None) -> dict[str, np.ndarray | int]:
    """``kernel`` (compiled or not) on ``model`` at ``(q, v, a)``, the joints given in model order."""
    nv, n = model.nv, len(frames) - 1
    tables = kernels.joint_tables(model, frames)
    out = {"jacobians": np.zeros((n + 1, 6, nv)), "motion": np.zeros((n + 1, 6)), "relative": np.zeros((n, 6)),
           "rotations": np.zeros((n, 3, 3)), "angular": np.zeros((n, 3)), "bias": np.zeros(nv - 6), "wrenches": np.zeros((n, 6))}
    base_q, base_v, base_a = q.copy(), v.copy(), a.copy()
    base_q[7:], base_v[6:], base_a[6:] = 0.0, 0.0, 0.0  # the kernel gathers the joints itself
    mode = kernels.DYNAMICS | kernels.INERTIAL | (kernels.SOLVE if legs is not None else 0)
    out["info"] = kernel(*tables, np.array(model.gravity.linear), legs if legs is not None else np.zeros((n, 6), np.int64),
                         np.arange(nv - 6), base_q, base_v, base_a, q[7:].copy(), v[6:].copy(), efforts, a[6:].copy(), mode,
                         out["jacobians"], out["motion"], out["relative"], out["rotations"], out["angular"], out["bias"],
                         out["wrenches"])
    return out


def _random_state(model: pin.Model, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    q = pin.neutral(model)
    quaternion = rng.normal(size=4)
    q[3:7] = quaternion / np.linalg.norm(quaternion)
    q[7:] = rng.uniform(-1.2, 1.2, model.nq - 7)
    v = rng.normal(0.0, 2.0, model.nv)
    v[:3] = 0.0  # the base origin does not translate (the estimator's frame)
    a = rng.normal(0.0, 5.0, model.nv)
    return q, v, a


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "python"])
def test_leg_kinematics_kernel_matches_pinocchio_on_the_g1_legs(g1: RobotDescription, compiled: bool) -> None:
    """Frame placements, LOCAL_WORLD_ALIGNED Jacobians and velocities, RNEA torques (armature
    included) and the feet's wrenches on 20 random states of the G1's legs, equal to Pinocchio's to
    rounding, compiled and uncompiled."""
    kin = LegKinematics(g1)
    model, frames = kin._legs, list(kin._frames)
    data = model.createData()
    legs = kin._leg_column_table
    kernel = kernels.leg_kinematics if compiled else kernels.reference(kernels.leg_kinematics)
    rng = np.random.default_rng(37)
    for _ in range(20):
        q, v, a = _random_state(model, rng)
        efforts = rng.normal(0.0, 20.0, model.nv - 6)
        out = _run_leg_kinematics(kernel, model, frames, q, v, a, efforts, legs)
        assert out["info"] == 0
        pin.computeJointJacobians(model, data, q)
        for k, frame in enumerate(frames):
            placement = pin.updateFramePlacement(model, data, frame)
            jacobian = pin.getFrameJacobian(model, data, frame, LWA)
            np.testing.assert_allclose(out["motion"][k, :3], placement.translation, rtol=0, atol=1e-14)
            np.testing.assert_allclose(out["jacobians"][k], jacobian, rtol=0, atol=1e-14)
            np.testing.assert_allclose(out["motion"][k, 3:], jacobian[:3] @ v, rtol=0, atol=1e-13)
            if k < len(frames) - 1:
                np.testing.assert_allclose(out["rotations"][k], placement.rotation, rtol=0, atol=1e-14)
                np.testing.assert_allclose(out["angular"][k], jacobian[3:] @ v, rtol=0, atol=1e-13)
                np.testing.assert_allclose(out["relative"][k], out["motion"][k] - out["motion"][-1], rtol=0, atol=1e-15)
        torques = pin.rnea(model, data, q, v, a)[6:]
        np.testing.assert_allclose(out["bias"], torques - efforts, rtol=0, atol=1e-11 * np.abs(torques).max())
        for foot in range(len(frames) - 1):  # J_leg^T w = bias, each leg
            columns = legs[foot]
            np.testing.assert_allclose(out["jacobians"][foot][:, columns].T @ out["wrenches"][foot], out["bias"][columns - 6],
                                       rtol=0, atol=1e-10 * np.abs(out["bias"]).max())


def test_leg_kinematics_kernel_handles_unaligned_and_prismatic_joints() -> None:
    """A free flyer carrying a revolute joint about a tilted axis, a prismatic one along another and a
    revolute z joint (random inertias, armatures, placements): the kernel equals Pinocchio there too,
    and a joint it does not know is refused at construction."""
    rng = np.random.default_rng(3)
    model = pin.Model()
    free = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    model.appendBodyToJoint(free, pin.Inertia.Random(), pin.SE3.Identity())
    parent = free
    for k, joint in enumerate((pin.JointModelRevoluteUnaligned(*(rng.normal(size=3) / 2.0)),
                               pin.JointModelPrismaticUnaligned(*(rng.normal(size=3) / 2.0)), pin.JointModelRZ())):
        if hasattr(joint, "axis"):
            joint.axis = joint.axis / np.linalg.norm(joint.axis)
        parent = model.addJoint(parent, joint, pin.SE3.Random(), f"joint{k}")
        model.appendBodyToJoint(parent, pin.Inertia.Random(), pin.SE3.Identity())
    model.armature = rng.uniform(0.0, 0.05, model.nv)
    model.armature[:6] = 0.0
    foot = model.addFrame(pin.Frame("foot", parent, 0, pin.SE3.Random(), pin.FrameType.OP_FRAME), False)
    imu = model.addFrame(pin.Frame("imu", free, 0, pin.SE3.Random(), pin.FrameType.OP_FRAME), False)
    data = model.createData()
    for _ in range(10):
        q, v, a = _random_state(model, rng)
        efforts = rng.normal(0.0, 5.0, model.nv - 6)
        out = _run_leg_kinematics(kernels.leg_kinematics, model, [foot, imu], q, v, a, efforts, None)
        pin.computeJointJacobians(model, data, q)
        for k, frame in enumerate((foot, imu)):
            np.testing.assert_allclose(out["motion"][k, :3], pin.updateFramePlacement(model, data, frame).translation, atol=1e-13)
            np.testing.assert_allclose(out["jacobians"][k], pin.getFrameJacobian(model, data, frame, LWA), atol=1e-13)
        np.testing.assert_allclose(out["bias"], pin.rnea(model, data, q, v, a)[6:] - efforts, atol=1e-11)
    spherical = pin.Model()
    spherical.addJoint(spherical.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base"), pin.JointModelSpherical(),
                       pin.SE3.Identity(), "ball")
    with pytest.raises(NotImplementedError, match="ball"):
        kernels.joint_tables(spherical, [0])


def _textbook_filter(n: int, noise: LegKalmanNoise, x: np.ndarray, P: np.ndarray, steps: list) -> tuple[np.ndarray, np.ndarray]:
    """The leg Kalman filter written out over its full 3 (2 + n) state (axis-major blocks), numpy only:
    what the per-axis kernels must reproduce."""
    s = 2 + n
    X, C = x.reshape(-1).copy(), np.kron(np.eye(3), P)
    for acceleration, dt, stance, positions, velocities, position_ok, velocity_ok, gate in steps:
        F = np.eye(s)
        F[0, 1] = dt
        B = np.array([0.5 * dt * dt, dt] + [0.0] * n)
        q = [noise.position**2 * dt, noise.acceleration**2 * dt] + [min(noise.stance_foot / max(c, 1e-6), noise.swing_foot) ** 2 * dt
                                                                       for c in stance]
        X = np.kron(np.eye(3), F) @ X + np.kron(acceleration, B)
        C = np.kron(np.eye(3), F) @ C @ np.kron(np.eye(3), F).T + np.kron(np.eye(3), np.diag(q))
        H = np.zeros((2 * n, s))
        for i in range(n):
            H[i, 0], H[i, 2 + i], H[n + i, 1] = -1.0, 1.0, -1.0
        used = np.array(list(position_ok) + [c > 0 and ok for c, ok in zip(stance, velocity_ok)])
        H = H * used[:, None]
        variances = [noise.foot_position**2] * n
        for i, c in enumerate(stance):
            variance = noise.foot_velocity**2 / max(c, 1e-3) ** 2
            innovation = velocities[i] + X[1::s]
            nis = float(np.sum(innovation**2 / (np.diag(C)[1::s] + variance)))
            variances.append(variance * (nis / gate if nis > gate else 1.0))
        HH = np.kron(np.eye(3), H)
        z = np.concatenate([np.concatenate([positions[:, axis], velocities[:, axis]]) * used for axis in range(3)])
        S = HH @ C @ HH.T + np.kron(np.eye(3), np.diag(variances))
        K = C @ HH.T @ np.linalg.inv(S)
        X = X + K @ (z - HH @ X)
        C = C - K @ HH @ C
    return X.reshape(3, s), C


def test_kalman_kernels_reproduce_the_full_state_filter() -> None:
    """200 predictions and corrections with random accelerations, stance confidences, swing feet, a
    leg left out now and then and the velocity gate firing: the per-axis compiled filter's state and
    covariance equal the textbook filter over all 12 states (to 1e-9 relative)."""
    rng = np.random.default_rng(11)
    n, noise = 2, LegKalmanNoise()
    kalman = LegKalmanFilter(n, noise, velocity_gate=11.3, gate_power=1.0)
    kalman.initialize(np.array([0.0, 0.1, 0.8]), np.array([[0.0, 0.2, 0.0], [0.0, 0.0, 0.0]]))
    x0, P0 = kalman.x.copy(), kalman.P[0].copy()
    steps = []
    for _ in range(200):
        acceleration = rng.normal(0.0, 2.0, 3)
        stance = [float(c) if c > 0.3 else 0.0 for c in rng.uniform(0.0, 1.0, n)]
        positions = rng.normal(0.0, 0.3, (n, 3))
        velocities = rng.normal(0.0, 0.3, (n, 3))
        position_ok = rng.uniform(size=n) > 0.1
        velocity_ok = position_ok & (rng.uniform(size=n) > 0.1)
        steps.append((acceleration, 0.002, stance, positions, velocities, position_ok, velocity_ok, 11.3))
        kalman.predict(acceleration, 0.002, stance)
        kalman.correct(positions, velocities, stance, position_ok, velocity_ok)
    x, C = _textbook_filter(n, noise, x0, P0, steps)
    np.testing.assert_allclose(kalman.x, x, rtol=1e-9, atol=1e-12)
    full = np.kron(np.eye(3), np.zeros((4, 4)))
    for axis in range(3):
        full[4 * axis : 4 * axis + 4, 4 * axis : 4 * axis + 4] = kalman.P[axis]
    np.testing.assert_allclose(full, C, rtol=1e-9, atol=1e-15)


def _same(compiled: object, python: object) -> None:
    if isinstance(compiled, tuple):
        np.testing.assert_allclose(compiled, python, rtol=1e-13, atol=1e-15)
    else:
        assert compiled == python


@pytest.mark.parametrize("trial", range(5))
def test_small_kernels_compiled_equal_their_python_function(trial: int) -> None:
    """Each of the estimator's small kernels on random inputs, compiled and uncompiled: the same
    outputs (in place and returned) to rounding."""
    rng = np.random.default_rng(100 + trial)
    rotation = tuple(np.linalg.qr(rng.normal(size=(3, 3)))[0].reshape(-1).tolist())
    imu_rotation = tuple(np.linalg.qr(rng.normal(size=(3, 3)))[0].reshape(-1).tolist())
    vector = lambda: tuple(rng.normal(size=3).tolist())  # noqa: E731
    cases = {
        "pivot_velocities": lambda: (rng.normal(0.0, 100.0, (2, 6)), rng.normal(size=(2, 3, 3)), rng.normal(size=(2, 3)),
                                     rng.normal(size=(2, 3)), np.array([[0.1, 0.03], [0.1, 0.03]]), np.zeros((2, 3))),
        "leg_accelerations": lambda: (rng.normal(size=29), rng.normal(size=29), np.zeros(29), rng.normal(size=6), bool(trial % 2),
                                      trial == 3, vector(), vector(), trial != 4, rotation, imu_rotation, vector(),
                                      (0.0, 0.0, -9.81), 0.3, 140.0, np.zeros(6)),
        "compensated_up": lambda: (vector(), vector(), rotation, imu_rotation, (float(trial > 1), 0.4), rng.normal(size=(2, 3)),
                                   rng.normal(size=(3, 4)), rng.normal(size=6), trial == 0, 0.02, 9.8),
        "effort_forces": lambda: (rng.normal(0.0, 200.0, (2, 6)), np.array([True, trial != 2]), rng.normal(0.0, 0.6, (2, 3)),
                                  rng.normal(0.0, 0.3, (3, 4)), 1.0 if trial else 0.0, trial == 4, rng.normal(0.0, 50.0, (2, 3))),
        "detect_contacts": lambda: (np.array([rng.normal(0.0, 200.0), np.nan if trial == 1 else 300.0]), np.array([trial != 2, True]),
                                    rng.uniform(0.0, 400.0, 2), trial != 0, 0.17, 40.0, 20.0, np.array([trial % 2 == 0, True]),
                                    np.zeros(2, bool)),
        "still_feet": lambda: (rng.normal(0.0, 2.0, (2, 3)), (0.8 * trial / 4, 0.0), rng.uniform(0.0, 4.0, 2), np.array([-np.inf, 1.0]),
                               2.5, 0.1, 1.0, 0.1, np.zeros(2)),
        "rolling_trust": lambda: (np.array([[np.nan if trial == 1 else 0.3, 0.1, 2.0], [0.0, 0.0, 0.1]]), (0.9, 0.5 * (trial % 2)),
                                  rng.uniform(0.0, 4.0, 2), 0.1, 4.0, np.zeros(2)),
        "pull_to_ground": lambda: (rng.normal(size=(3, 4)), (True, trial > 2), (0.7, 0.2), 0.0, 0.004),
        "assemble_state": lambda: (rng.normal(size=(3, 4)), rng.normal(size=3), rotation, tuple(rng.normal(size=4).tolist()),
                                   vector(), rng.normal(size=29), rng.normal(size=29), np.zeros(36), np.zeros(35), np.zeros(13)),
    }
    for name, make in cases.items():
        kernel = getattr(kernels, name)
        arguments = make()
        copies = [a.copy() if isinstance(a, np.ndarray) else a for a in arguments]
        compiled, python = kernel(*arguments), kernels.reference(kernel)(*copies)
        _same(compiled, python)
        for mine, theirs in zip(arguments, copies):
            if isinstance(mine, np.ndarray):
                np.testing.assert_allclose(mine, theirs, rtol=1e-13, atol=1e-15, err_msg=name)


def test_kernels_compile_without_a_writable_cache_folder(tmp_path: Path) -> None:
    """No cache folder can be written (a read-only installation without NUMBA_CACHE_DIR or a user
    cache): the kernels still compile, at the first call, and compute."""
    blocked = tmp_path / "a_file"
    blocked.write_text("")
    package = tmp_path / "readonly"
    package.mkdir()
    shutil.copy(kernels.__file__, package / "k37.py")
    (package / "__pycache__").write_text("")  # numba's in-tree cache folder cannot be made
    environment = {**os.environ, "NUMBA_CACHE_DIR": str(blocked / "numba"), "XDG_CACHE_HOME": str(blocked / "cache"),
                   "HOME": str(blocked)}
    script = ("import sys, numpy as np; sys.path.insert(0, sys.argv[1]); import k37; "
              "x = np.zeros((3, 4)); x[2] = 1.0; k37.pull_to_ground(x, (True, True), (1.0, 1.0), 0.0, 1.0); "
              "from numba.core.caching import NullCache; assert isinstance(k37.pull_to_ground._cache, NullCache); "
              "print(x[2].tolist())")
    result = subprocess.run([sys.executable, "-c", script, str(package)], env=environment, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["[0.0,", "1.0,", "0.0,", "0.0]"]  # heights pulled onto the ground, the velocity left


KERNELS = ("leg_kinematics", "kalman_predict", "kalman_correct", "pivot_velocities", "leg_accelerations", "compensated_up",
           "pull_to_ground", "assemble_state", "effort_forces", "detect_contacts", "still_feet", "rolling_trust")


@pytest.mark.slow
def test_estimates_of_a_closed_loop_walk_compiled_equal_uncompiled(g1: RobotDescription, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every measurement the estimator got in 2 s of G1Walk-v0 with the shipped policy's kwargs
    (estimator in the loop, ANY_FEET, AHRS IMU; its start-up calibration included), replayed through
    a fresh estimator with the compiled kernels and with their Python functions: the same contacts,
    and q, v, contact forces and covariance within 1e-9 of their scale."""
    path = shipped_policy("g1_walk_residual")
    if path is None:
        pytest.skip("the shipped walking policy is not installed")
    env = gymnasium.make(giwbc.envs.G1_WALK, **dict(OnnxPolicy(path).metadata["env_kwargs"])).unwrapped
    estimator = env.task.robot.estimator
    stream: list[tuple[Measurement, np.ndarray | None]] = []
    update = estimator.update

    def recording(measurement: Measurement, contacts: np.ndarray | None = None):  # type: ignore[no-untyped-def]
        imu = measurement.imu
        copy = Measurement(ImuReading(np.array(imu.quaternion), np.array(imu.angular_velocity), np.array(imu.linear_acceleration),
                                      float(imu.time)),
                           np.array(measurement.joint_positions), np.array(measurement.joint_velocities),
                           np.array(measurement.joint_efforts))
        stream.append((copy, None if contacts is None else np.array(contacts, bool)))
        return update(measurement, contacts)

    estimator.update = recording
    env.reset(seed=5)
    actions = np.random.default_rng(5).uniform(-0.3, 0.3, (100, *env.action_space.shape)).astype(env.action_space.dtype)
    for action in actions:
        if any(env.step(action)[2:4]):
            break
    env.close()
    assert len(stream) > 1000  # the calibration and 2 s at 500 Hz

    def replay() -> dict[str, np.ndarray]:
        fresh = StateEstimator(g1, estimator.config)
        estimates = [fresh.update(measurement, plan) for measurement, plan in stream]
        assert estimates[-1].ready
        return {"q": np.array([e.q for e in estimates]), "v": np.array([e.v for e in estimates]),
                "forces": np.array([e.contact_forces for e in estimates]), "covariance": np.array([e.covariance for e in estimates]),
                "contacts": np.array([e.contacts for e in estimates])}

    compiled = replay()
    assert set(KERNELS) == {name for name in kernels.__all__ if hasattr(getattr(kernels, name), "py_func")}  # every kernel
    for name in KERNELS:
        monkeypatch.setattr(kernels, name, kernels.reference(getattr(kernels, name)))
    python = replay()
    np.testing.assert_array_equal(compiled["contacts"], python["contacts"])
    for name in ("q", "v", "forces", "covariance"):
        scale = float(np.max(np.abs(python[name])))
        np.testing.assert_allclose(compiled[name], python[name], rtol=0, atol=1e-9 * scale, err_msg=name)


@pytest.mark.parametrize("trial", range(4))
def test_sensor_model_kernels_compiled_equal_their_python_function(trial: int) -> None:
    """The AHRS sensor model's per-physics-step kernels (giwbc.robot.noise) on random truths and
    errors (mounting, bias walks, ranges, orientation output off in one trial), compiled and not:
    the same sample and bias walk; the encoder's quantization leaves multiples of its resolution."""
    from giwbc.robot import noise

    rng = np.random.default_rng(200 + trial)
    quaternion = rng.normal(size=4)
    constants = np.concatenate([np.linalg.qr(rng.normal(size=(3, 3)))[0].reshape(-1), quaternion / np.linalg.norm(quaternion),
                                rng.normal(0.0, 0.01, 3), (1e-4, 1e-3 * trial, 1e-2, 0.01, 0.05, 3.0 if trial else np.inf, 40.0, 0.005)])
    imu_args = (quaternion / np.linalg.norm(quaternion), rng.normal(0.0, 2.0, 3), rng.normal(0.0, 15.0, 3), 12.5, 0.05,
                rng.normal(size=15), rng.normal(0.0, 0.01, 3), rng.normal(0.0, 0.1, 3), constants, trial != 1, trial != 2, trial != 3,
                np.zeros(10))
    n = 29
    joint_args = (rng.normal(size=15 + 3 * n), np.abs(rng.normal(0.0, 0.01, (3, n))), rng.normal(size=n), rng.normal(0.0, 0.01, n),
                  trial % 2 == 0, 0.0 if trial == 3 else 3.8e-4, rng.normal(size=n), rng.normal(size=n), np.zeros((3, n)))
    for kernel, arguments in ((noise._measure_imu_kernel, imu_args), (noise._measure_joints, joint_args)):
        copies = [a.copy() if isinstance(a, np.ndarray) else a for a in arguments]
        kernel(*arguments)
        kernels.reference(kernel)(*copies)
        for mine, theirs in zip(arguments, copies):
            if isinstance(mine, np.ndarray):
                np.testing.assert_allclose(mine, theirs, rtol=1e-14, atol=1e-15)
    if trial != 3:
        steps = joint_args[-1][0] / 3.8e-4
        np.testing.assert_allclose(steps, np.round(steps), rtol=0, atol=1e-6)
    assert np.isnan(imu_args[-1][:4]).all() == (trial == 2)
