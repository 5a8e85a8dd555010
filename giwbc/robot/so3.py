"""Small SO(3) helpers on plain numpy (quaternions ``(x, y, z, w)``, like the Robot interface).

Written for 3-vectors and 3x3 matrices one at a time: the estimator calls them once per update,
where Python call overhead, not flops, is the cost, so they avoid generic machinery. The
``*_floats`` helpers, :func:`rotate` and :func:`rotate_back` work on tuples of Python floats (a matrix as its 9 entries,
row by row): on single 3-vectors, a dozen float operations cost less than one numpy call.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from giwbc.robot.interface import quat_to_matrix

__all__ = [
    "Matrix3",
    "Quaternion",
    "Vector3",
    "as_floats",
    "cross",
    "cross_floats",
    "exp",
    "log",
    "matrix_to_quat",
    "quat_conjugate",
    "quat_multiply",
    "quat_multiply_floats",
    "quat_to_matrix",
    "quat_to_matrix_floats",
    "rotate",
    "quat_to_rpy",
    "rotate_back",
    "rotation_angle",
    "rpy_to_matrix",
    "rpy_to_quat",
    "skew",
]

Vector3 = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]
Matrix3 = tuple[float, float, float, float, float, float, float, float, float]  # row by row


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` for 3-vectors (np.cross costs ~10x more on single vectors)."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def skew(w: np.ndarray) -> np.ndarray:
    """The cross-product matrix ``[w]x`` with ``[w]x @ u == cross(w, u)``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` (Rodrigues' formula)."""
    angle = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    k = skew(w)
    if angle < 1e-8:
        return np.eye(3) + k + 0.5 * (k @ k)
    return np.eye(3) + (math.sin(angle) / angle) * k + ((1.0 - math.cos(angle)) / (angle * angle)) * (k @ k)


def log(rotation: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (inverse of :func:`exp` for angles below pi)."""
    vee = np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0], rotation[1, 0] - rotation[0, 1]])
    cos_angle = min(1.0, max(-1.0, 0.5 * (rotation[0, 0] + rotation[1, 1] + rotation[2, 2] - 1.0)))
    angle = math.acos(cos_angle)
    sin_angle = math.sin(angle)
    if sin_angle < 1e-6:
        if cos_angle > 0:  # near identity
            return 0.5 * vee
        # near pi: the axis is the dominant column of R + I
        column = int(np.argmax(np.diag(rotation)))
        axis = (rotation[:, column] + np.eye(3)[:, column]) / math.sqrt(2.0 * (1.0 + rotation[column, column]))
        return angle * axis
    return (0.5 * angle / sin_angle) * vee


def rotation_angle(rotation: np.ndarray) -> float:
    """Angle (rad) of a rotation matrix, in [0, pi]."""
    return math.acos(min(1.0, max(-1.0, 0.5 * (rotation[0, 0] + rotation[1, 1] + rotation[2, 2] - 1.0))))


def matrix_to_quat(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` (with ``w >= 0``) of a rotation matrix."""
    r = rotation
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        quat = np.array([(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s])
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        quat = np.array([0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s])
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        quat = np.array([(r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s])
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        quat = np.array([(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s, (r[1, 0] - r[0, 1]) / s])
    if quat[3] < 0.0:
        quat = -quat
    return quat / np.linalg.norm(quat)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of quaternions ``(x, y, z, w)``: rotation ``b`` then ``a``."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """The inverse rotation of a unit quaternion ``(x, y, z, w)``."""
    return np.array([-q[0], -q[1], -q[2], q[3]])


# --- on Python floats -------------------------------------------------------------------------
def as_floats(values: Sequence[float]) -> Sequence[float]:
    """An array's entries as Python floats (arithmetic on numpy scalars is slower); other
    sequences as they are."""
    return values.tolist() if isinstance(values, np.ndarray) else values


def quat_multiply_floats(a: Sequence[float], b: Sequence[float]) -> Quaternion:
    """:func:`quat_multiply` on floats."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def quat_to_matrix_floats(q: Sequence[float]) -> Matrix3:
    """:func:`quat_to_matrix` on floats: the 9 entries, row by row."""
    x, y, z, w = q
    return (
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    )  # fmt: skip


def rotate(m: Matrix3, v: Sequence[float]) -> Vector3:
    """``M @ v`` for a matrix given row by row."""
    x, y, z = v
    return (m[0] * x + m[1] * y + m[2] * z, m[3] * x + m[4] * y + m[5] * z, m[6] * x + m[7] * y + m[8] * z)


def rotate_back(m: Matrix3, v: Sequence[float]) -> Vector3:
    """``M.T @ v`` for a matrix given row by row (the inverse rotation)."""
    x, y, z = v
    return (m[0] * x + m[3] * y + m[6] * z, m[1] * x + m[4] * y + m[7] * z, m[2] * x + m[5] * y + m[8] * z)


def cross_floats(a: Sequence[float], b: Sequence[float]) -> Vector3:
    """``a x b`` on floats."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)


def rpy_to_quat(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Quaternion ``(x, y, z, w)`` of roll-pitch-yaw angles (rad): ``R = Rz(yaw) Ry(pitch) Rx(roll)``,
    the aerospace Z-Y-X convention most IMUs report Euler angles in."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return np.array(
        [sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy]
    )



def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw (rad) as a rotation matrix: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy), np.sin(rpy)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )

def quat_to_rpy(q: Sequence[float]) -> Vector3:
    """Roll, pitch, yaw (rad) of a unit quaternion ``(x, y, z, w)``, inverse of :func:`rpy_to_quat`
    (pitch in [-pi/2, pi/2])."""
    x, y, z, w = (float(v) for v in q)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return (roll, pitch, yaw)
