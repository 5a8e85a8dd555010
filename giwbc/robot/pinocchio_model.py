"""Build the Pinocchio model of a robot description (free-flyer root for a floating base)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from giwbc.errors import RobotDescriptionError

if TYPE_CHECKING:
    from giwbc.robot.description import RobotDescription


def build_pinocchio_model(description: RobotDescription) -> pin.Model:
    """The Pinocchio model, its joints checked against the description's order, armature set."""
    root = pin.JointModelFreeFlyer() if description.floating_base else None
    try:
        if root is None:
            model = pin.buildModelFromXML(description.urdf_text())
        else:
            model = pin.buildModelFromXML(description.urdf_text(), root)
    except (RuntimeError, ValueError) as error:
        raise RobotDescriptionError(f"{description.urdf_path}: Pinocchio cannot parse the URDF: {error}") from error
    model.name = description.name
    first = 2 if description.floating_base else 1
    model_joints = tuple(model.names[first:])
    if model_joints != description.joint_names:
        raise RobotDescriptionError(
            f"{description.folder / 'robot.toml'}: joint order differs from the model's kinematic order; "
            f"list the joints as {list(model_joints)}"
        )
    if model.nq - (7 if root is not None else 0) != description.dofs:
        raise RobotDescriptionError(f"{description.urdf_path}: only single-DoF joints with nq == nv are supported")
    offset = 6 if root is not None else 0
    model.armature[offset:] = np.array([j.armature for j in description.joints])
    model.effortLimit[offset:] = description.effort_limits
    return model
