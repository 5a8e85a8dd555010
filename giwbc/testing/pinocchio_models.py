"""Pinocchio twins of the closed-form models in ``giwbc.testing.analytic``.

Each builder assembles a ``pinocchio.Model`` joint by joint (``addJoint`` +
``appendBodyToJoint``) from the *same* dataclass of parameters, following the conventions of
``analytic``: motion in the world x–z plane, revolute joints ``JointModelRY`` (about +y), gravity
along −z. Planar floating bases are the chain ``PX → PZ → RY`` so that ``nq == nv`` and
``q = [x, z, θ, …]`` means the same thing in both models. Only the y-axis moment of a body's
3×3 rotational inertia matters in the plane; the twins use ``diag(I, I, I)``.
"""

from __future__ import annotations

from functools import singledispatch

import numpy as np
import pinocchio as pin

from giwbc.testing.analytic import (
    CartPole,
    DoublePendulum,
    PlanarFloatingArm,
    PlanarFloatingBody,
    SimplePendulum,
)

__all__ = [
    "build_pinocchio_model",
    "simple_pendulum_model",
    "double_pendulum_model",
    "cart_pole_model",
    "planar_floating_body_model",
    "planar_floating_arm_model",
]


def _translation(x: float = 0.0, z: float = 0.0) -> pin.SE3:
    return pin.SE3(np.eye(3), np.array([x, 0.0, z]))


def _planar_inertia(mass: float, com_x: float, com_z: float, inertia_y: float) -> pin.Inertia:
    """Spatial inertia of a body with CoM at ``(com_x, 0, com_z)`` in its joint frame."""
    return pin.Inertia(mass, np.array([com_x, 0.0, com_z]), inertia_y * np.eye(3))


def _empty_model(name: str, gravity_acc: float) -> pin.Model:
    model = pin.Model()
    model.name = name
    model.gravity = pin.Motion(np.array([0.0, 0.0, -gravity_acc]), np.zeros(3))
    return model


def _add_planar_base(model: pin.Model) -> int:
    """``PX → PZ → RY`` chain from the world, named ``base_x``, ``base_z``, ``base_pitch``.

    Returns the id of the pitch joint, which carries the base body.
    """
    jx = model.addJoint(0, pin.JointModelPX(), pin.SE3.Identity(), "base_x")
    jz = model.addJoint(jx, pin.JointModelPZ(), pin.SE3.Identity(), "base_z")
    return model.addJoint(jz, pin.JointModelRY(), pin.SE3.Identity(), "base_pitch")


def _add_joint_with_body(model: pin.Model, parent: int, joint: pin.JointModel, placement: pin.SE3, name: str, inertia: pin.Inertia) -> int:
    joint_id = model.addJoint(parent, joint, placement, name)
    model.appendBodyToJoint(joint_id, inertia, pin.SE3.Identity())
    model.addJointFrame(joint_id)
    model.addBodyFrame(f"{name}_body", joint_id, pin.SE3.Identity(), model.nframes - 1)
    return joint_id


@singledispatch
def build_pinocchio_model(params: object) -> pin.Model:
    """Pinocchio twin of any model in ``giwbc.testing.analytic``."""
    raise TypeError(f"no Pinocchio twin for {type(params).__name__}")


@build_pinocchio_model.register
def simple_pendulum_model(params: SimplePendulum) -> pin.Model:
    """Joint ``pivot`` (RY) at the origin; CoM at ``(0, 0, −com_distance)`` in the link frame."""
    model = _empty_model("simple_pendulum", params.gravity_acc)
    body = _planar_inertia(params.mass, 0.0, -params.com_distance, params.inertia)
    _add_joint_with_body(model, 0, pin.JointModelRY(), pin.SE3.Identity(), "pivot", body)
    return model


@build_pinocchio_model.register
def double_pendulum_model(params: DoublePendulum) -> pin.Model:
    """Joints ``joint1`` (origin) and ``joint2`` (``length1`` down link 1), both RY."""
    model = _empty_model("double_pendulum", params.gravity_acc)
    link1 = _planar_inertia(params.mass1, 0.0, -params.com1, params.inertia1)
    link2 = _planar_inertia(params.mass2, 0.0, -params.com2, params.inertia2)
    j1 = _add_joint_with_body(model, 0, pin.JointModelRY(), pin.SE3.Identity(), "joint1", link1)
    j2 = _add_joint_with_body(model, j1, pin.JointModelRY(), _translation(z=-params.length1), "joint2", link2)
    model.addFrame(pin.Frame("tip", j2, _translation(z=-params.length2), pin.FrameType.OP_FRAME))
    return model


@build_pinocchio_model.register
def cart_pole_model(params: CartPole) -> pin.Model:
    """Joint ``linear`` (PX) carrying the cart, joint ``pivot`` (RY) at ``pivot_height``.

    Same joint names and axes as ``robots/cartpole/cartpole.urdf``: the cart joint frame sits at
    the cart's CoM, ``cart_com_offset`` relative to the pivot. The cart's rotational inertia
    cannot move (prismatic joint) and is left at zero.
    """
    model = _empty_model("cartpole", params.gravity_acc)
    cart = _planar_inertia(params.cart_mass, 0.0, 0.0, 0.0)
    pole = _planar_inertia(params.pole_mass, 0.0, params.pole_com, params.pole_inertia)
    cart_z = params.pivot_height + params.cart_com_offset
    j_cart = _add_joint_with_body(model, 0, pin.JointModelPX(), _translation(z=cart_z), "linear", cart)
    _add_joint_with_body(model, j_cart, pin.JointModelRY(), _translation(z=-params.cart_com_offset), "pivot", pole)
    return model


@build_pinocchio_model.register
def planar_floating_body_model(params: PlanarFloatingBody) -> pin.Model:
    """``PX → PZ → RY`` base with the body on the pitch joint."""
    model = _empty_model("planar_floating_body", params.gravity_acc)
    base = _add_planar_base(model)
    model.appendBodyToJoint(base, _planar_inertia(params.mass, params.com_x, params.com_z, params.inertia), pin.SE3.Identity())
    model.addJointFrame(base)
    return model


@build_pinocchio_model.register
def planar_floating_arm_model(params: PlanarFloatingArm) -> pin.Model:
    """``PX → PZ → RY`` base, then joint ``arm`` (RY) at ``(joint_x, joint_z)`` in the base frame.

    An operational frame ``tip`` sits ``link_length`` down the link.
    """
    model = _empty_model("planar_floating_arm", params.gravity_acc)
    base = _add_planar_base(model)
    model.appendBodyToJoint(
        base,
        _planar_inertia(params.base_mass, params.base_com_x, params.base_com_z, params.base_inertia),
        pin.SE3.Identity(),
    )
    model.addJointFrame(base)
    link = _planar_inertia(params.link_mass, 0.0, -params.link_com, params.link_inertia)
    arm = _add_joint_with_body(model, base, pin.JointModelRY(), _translation(params.joint_x, params.joint_z), "arm", link)
    model.addFrame(pin.Frame("tip", arm, _translation(z=-params.link_length), pin.FrameType.OP_FRAME))
    return model
