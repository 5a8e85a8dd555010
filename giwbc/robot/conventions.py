"""Free-flyer conventions: MuJoCo's ``qpos/qvel`` against Pinocchio's ``q/v``.

MuJoCo: ``qpos = [p, quat_wxyz, joints]``, ``qvel = [v_world, w_local, joints]``.
Pinocchio: ``q = [p, quat_xyzw, joints]``, ``v = [v_local, w_local, joints]``.
"""

from __future__ import annotations

import numpy as np

from giwbc.robot.interface import quat_to_matrix


_XYZW = np.array([1, 2, 3, 0])
_XYZW.flags.writeable = False


def wxyz_to_xyzw(quat: np.ndarray) -> np.ndarray:
    if type(quat) is np.ndarray:
        return quat[_XYZW]  # (a new array, one gather: the same entries as the list below)
    return np.array([quat[1], quat[2], quat[3], quat[0]])


def xyzw_to_wxyz(quat: np.ndarray) -> np.ndarray:
    return np.array([quat[3], quat[0], quat[1], quat[2]])


def mujoco_to_pinocchio(qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Free-flyer MuJoCo state to Pinocchio ``(q, v)``."""
    quat = wxyz_to_xyzw(qpos[3:7])
    rotation = quat_to_matrix(quat)
    q = np.concatenate([qpos[:3], quat, qpos[7:]])
    v = np.concatenate([rotation.T @ qvel[:3], qvel[3:]])
    return q, v


def pinocchio_to_mujoco(q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinocchio free-flyer ``(q, v)`` to MuJoCo ``(qpos, qvel)``."""
    rotation = quat_to_matrix(q[3:7])
    qpos = np.concatenate([q[:3], xyzw_to_wxyz(q[3:7]), q[7:]])
    qvel = np.concatenate([rotation @ v[:3], v[3:]])
    return qpos, qvel


def velocity_map(q: np.ndarray, nv: int) -> np.ndarray:
    """Matrix ``T`` with ``qvel = T v``: identity except the base-linear block, which is R."""
    transform = np.eye(nv)
    transform[:3, :3] = quat_to_matrix(q[3:7])
    return transform
