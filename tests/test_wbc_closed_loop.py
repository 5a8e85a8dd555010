"""The balance WBC in closed loop with MuJoCo: G1 at 500 Hz, torques through the actuators, the
controller reading MuJoCo's ground-truth state converted to Pinocchio's (q, v).

Ground truth for the checks comes from MuJoCo itself (whole-body CoM ``subtree_com`` of the
root body, sole corner heights from the link poses, foot touch sensors), not from the controller.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from giwbc.control import make_balance_controller
from giwbc.robot import MujocoRobot
from giwbc.robot.mujoco_model import foot_sensor_names

pytestmark = pytest.mark.slow
SOLVERS = ["proxsuite", "osqp"]


@dataclass
class Run:
    com: np.ndarray  # (ticks, 3) MuJoCo CoM
    com_ref: np.ndarray  # (ticks, 3) the controller's CoM target
    corner_lift: np.ndarray  # (2,) largest rise of any sole corner, per foot, m
    touch: np.ndarray  # (ticks, 2) foot normal forces (touch sensors), N
    failures: int
    tilt_deg: float


def simulate(g1, solver: str, seconds: float, *, sway: float = 0.0, push: float = 0.0) -> Run:
    """Stand for ``seconds``; optionally sway the CoM target laterally (±``sway`` m at 0.5 Hz, its
    amplitude eased in over the first second) or push the pelvis laterally (``push`` N for 0.2 s
    from t = 0.5 s)."""
    robot = MujocoRobot(g1)
    controller = make_balance_controller(g1, solver=solver)
    q, v = robot.generalized_state()
    controller.reset(q)
    dt = g1.timestep
    root = robot.model.body(g1.base_link).id
    touch = [foot_sensor_names(c.name)["touch"] for c in g1.contacts]
    corners0 = _corner_heights(robot, g1)
    lift = np.zeros(len(g1.contacts))
    coms, refs, forces = [], [], []
    omega = 2.0 * np.pi * 0.5
    for i in range(int(round(seconds / dt))):
        t = i * dt
        if sway:
            s, ds, dds = _ease(min(t, 1.0)) if t < 1.0 else (1.0, 0.0, 0.0)
            sin, cos = np.sin(omega * t), np.cos(omega * t)
            y = sway * s * sin
            vy = sway * (ds * sin + s * omega * cos)
            ay = sway * (dds * sin + 2 * ds * omega * cos - s * omega**2 * sin)
            controller.set_com_offset([0.0, y, 0.0], [0.0, vy, 0.0], [0.0, ay, 0.0])
        if push:
            robot.set_external_wrench(g1.base_link, [0.0, push if 0.5 <= t < 0.7 else 0.0, 0.0])
        controller.step(robot)  # reads (q, v), runs the WBC, commands the joint torques
        robot.step()
        coms.append(robot.data.subtree_com[root].copy())
        refs.append(controller.com_task.position_ref.copy())
        forces.append([robot.sensor(name)[0] for name in touch])
        lift = np.maximum(lift, (_corner_heights(robot, g1) - corners0).max(axis=1))
    base = robot.base_state()
    tilt = float(np.degrees(np.arccos(np.clip(base.rotation[2, 2], -1.0, 1.0))))
    return Run(np.array(coms), np.array(refs), lift, np.array(forces), controller.wbc.failures, tilt)


def _ease(x: float) -> tuple[float, float, float]:
    """Smoothstep 3x² − 2x³ and its first two derivatives."""
    return x * x * (3 - 2 * x), 6 * x - 6 * x * x, 6 - 12 * x


def _corner_heights(robot: MujocoRobot, g1) -> np.ndarray:
    heights = []
    for contact in g1.contacts:
        position, rotation = robot.link_pose(contact.link)
        heights.append((position + contact.corners @ rotation.T)[:, 2])
    return np.array(heights)


@pytest.mark.parametrize("solver", SOLVERS)
def test_stands_ten_seconds_without_com_drift(g1, solver):
    run = simulate(g1, solver, 10.0)
    assert run.failures == 0
    drift = np.linalg.norm(run.com - run.com[0], axis=1)
    assert drift.max() < 0.005, f"CoM drifted {drift.max() * 1e3:.2f} mm"
    assert run.corner_lift.max() < 0.001 and run.tilt_deg < 1.0


@pytest.mark.parametrize("solver", SOLVERS)
def test_tracks_a_lateral_com_sway(g1, solver):
    """±3 cm at 0.5 Hz: tracking error below 1 cm, and the CoM really does sway ±3 cm."""
    run = simulate(g1, solver, 5.0, sway=0.03)
    assert run.failures == 0
    error = np.linalg.norm(run.com - run.com_ref, axis=1)
    # The first tick's CoM defines the nominal target; MuJoCo's CoM is the ground truth.
    assert error.max() < 0.01, f"CoM tracking error {error.max() * 1e3:.2f} mm"
    lateral = run.com[:, 1] - run.com[0, 1]
    assert lateral.max() > 0.027 and lateral.min() < -0.027  # it does sway (±30 mm target, ~29 mm reached)
    assert run.corner_lift.max() < 0.002


@pytest.mark.parametrize("solver", SOLVERS)
def test_recovers_from_a_lateral_push_without_lifting_a_foot(g1, solver):
    """60 N on the pelvis for 0.2 s: both feet stay flat and loaded, the CoM comes back."""
    run = simulate(g1, solver, 3.0, push=60.0)
    assert run.failures == 0
    assert run.corner_lift.max() < 0.002, f"a sole corner rose {run.corner_lift.max() * 1e3:.2f} mm"
    # Each foot keeps carrying load (10 ms averages of the touch sensors).
    window = np.ones(5) / 5
    for foot in range(run.touch.shape[1]):
        assert np.convolve(run.touch[:, foot], window, "valid").min() > 5.0
    excursion = np.abs(run.com[:, 1] - run.com[0, 1]).max()
    assert 0.005 < excursion < 0.08  # it was pushed, and it gave way without falling
    assert np.linalg.norm(run.com[-1] - run.com[0]) < 0.01 and run.tilt_deg < 2.0
