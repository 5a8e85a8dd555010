"""The whole-body controller's answer against a second source of the dynamics.

On every solved tick of a closed loop on MuJoCo (the G1 standing, then pushed), with the output
clamp on τ inactive, the returned τ, q̈ and contact wrenches must satisfy ``M q̈ + h = Sᵀτ + Jᵀf``
with M and h from MuJoCo (``mj_fullM``, ``qfrc_bias``) and the contact Jacobians from ``mj_jac``,
in MuJoCo's coordinates: nothing in the check comes from the controller's own Pinocchio model.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from giwbc.control import ComTask, ContactForceRegularization, FrameOrientationTask, PostureTask, WholeBodyController, foot_contacts
from giwbc.robot import MujocoRobot, RobotDescription

SOLVERS = ["proxsuite", "osqp"]


def controller(g1: RobotDescription, model, solver: str) -> WholeBodyController:
    wbc = WholeBodyController(model, solver=solver, torque_limits=g1.effort_limits, dt=g1.timestep)
    for contact in foot_contacts(g1, "surface", mu=0.8):
        wbc.add_contact(contact)
    wbc.add_task(ComTask(weight=10.0, kp=100.0))
    wbc.add_task(FrameOrientationTask("pelvis", kp=100.0))
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
    wbc.add_task(ContactForceRegularization(weight=1e-5))
    return wbc


def mujoco_residual(mj_model, scratch, base: str, q: np.ndarray, v: np.ndarray, result, wbc: WholeBodyController) -> np.ndarray:
    """``M q̈ + h − Sᵀτ − Σ Jᵀ w`` in MuJoCo's coordinates, from MuJoCo's M, h and Jacobians at ``(q, v)``."""
    nv = mj_model.nv
    scratch.qpos[:3], scratch.qpos[3], scratch.qpos[4:7], scratch.qpos[7:] = q[:3], q[6], q[3:6], q[7:]
    mujoco.mj_forward(mj_model, scratch)  # positions first: the base rotation below is MuJoCo's own
    rotation = scratch.xmat[mj_model.body(base).id].reshape(3, 3)
    scratch.qvel[:3], scratch.qvel[3:] = rotation @ v[:3], v[3:]  # world linear, body angular
    mujoco.mj_forward(mj_model, scratch)
    mass = np.zeros((nv, nv))
    mujoco.mj_fullM(mj_model, scratch, mass)
    # MuJoCo's base acceleration is the time derivative of its world-frame linear velocity:
    # d/dt (R v_local) = R (v̇_local + ω × v_local).
    qacc = np.concatenate([rotation @ (result.qdd[:3] + np.cross(v[3:6], v[:3])), result.qdd[3:]])
    generalized = np.zeros(nv)
    generalized[6:] = result.tau
    jac_p, jac_r = np.zeros((3, nv)), np.zeros((3, nv))
    for name, wrench in result.contact_wrenches.items():
        contact = wbc.contact(name)
        body = mj_model.body(contact.link).id
        link_rotation = scratch.xmat[body].reshape(3, 3)
        point = scratch.xpos[body] + link_rotation @ contact.offset.translation
        axes = link_rotation @ contact.offset.rotation  # the contact frame's axes in the world
        mujoco.mj_jac(mj_model, scratch, jac_p, jac_r, point, body)
        generalized += jac_p.T @ (axes @ wrench[:3]) + jac_r.T @ (axes @ wrench[3:])
    return mass @ qacc + scratch.qfrc_bias - generalized


@pytest.mark.parametrize("solver", SOLVERS)
def test_every_solved_tick_satisfies_mujocos_equation_of_motion(g1: RobotDescription, solver: str) -> None:
    robot = MujocoRobot(g1)
    mj_model = robot.model
    scratch = mujoco.MjData(mj_model)
    wbc = controller(g1, g1.build_pinocchio(), solver)
    weight = g1.total_mass * 9.81
    checked = 0
    ticks = 250
    largest = 0.0
    for tick in range(ticks):
        push = 60.0 if 50 <= tick < 100 else 0.0  # 0.1 s sideways push
        robot.set_external_wrench("pelvis", np.array([0.0, push, 0.0]))
        q, v = robot.generalized_state()
        result = wbc.update(q, v)
        assert result.ok, (tick, result.message)
        clamp_inactive = np.all(np.abs(result.tau) < g1.effort_limits * (1 - 1e-9))
        if clamp_inactive:
            residual = mujoco_residual(mj_model, scratch, g1.base_link, q, v, result, wbc)
            largest = max(largest, float(np.max(np.abs(residual))))
            checked += 1
        robot.set_joint_torques(result.tau)
        robot.step()
    assert checked >= 0.9 * ticks  # the check ran on (nearly) every tick, not on none
    assert largest < 1e-5 * weight, largest
    # The loop did something: the push moved the robot, and the controller kept it standing.
    assert robot.base_state().position[2] > 0.9 * g1.default_base_position[2]
