"""IMU orientation: a complementary filter on SO(3) with gyro-bias estimation (Mahony's PI form).

The gyro propagates the orientation at full rate; the slow, drift-free references pull it back:
the IMU's own orientation output when it has one (its AHRS already fuses gravity and, for yaw,
whatever it uses), else the accelerometer's gravity direction (roll and pitch only, trusted only
while the specific force is close to 1 g). The integral of the correction estimates the gyro bias.

The filter keeps a unit quaternion in plain Python floats: per update it is a few dozen scalar
operations, far cheaper than numpy calls on 3-vectors.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from giwbc.robot import so3

__all__ = ["OrientationFilter"]

GRAVITY = 9.81


class OrientationFilter:
    """Orientation of one IMU in the world (``quaternion`` xyzw, ``rotation``) and its gyro bias.

    Gains are rates: ``orientation_gain`` (1/s) pulls toward the IMU's orientation output,
    ``accel_gain`` (1/s) toward the accelerometer's gravity direction, ``bias_gain`` (1/s^2)
    integrates the correction into the bias, clamped to ``max_bias`` (rad/s) per axis.
    """

    def __init__(
        self, orientation_gain: float = 2.0, accel_gain: float = 0.5, bias_gain: float = 0.2, max_bias: float = 0.1
    ) -> None:
        self.orientation_gain = orientation_gain
        self.accel_gain = accel_gain
        self.bias_gain = bias_gain
        self.max_bias = max_bias
        self.initialized = False
        self._q = (0.0, 0.0, 0.0, 1.0)
        self._bias = (0.0, 0.0, 0.0)

    @property
    def quaternion(self) -> np.ndarray:
        return np.array(self._q)

    @property
    def quaternion_floats(self) -> tuple[float, float, float, float]:
        """:attr:`quaternion` as Python floats."""
        return self._q

    @property
    def gyro_bias_floats(self) -> tuple[float, float, float]:
        """:attr:`gyro_bias` as Python floats."""
        return self._bias

    @property
    def rotation(self) -> np.ndarray:
        return so3.quat_to_matrix(self._q)

    @property
    def gyro_bias(self) -> np.ndarray:
        return np.array(self._bias)

    def initialize(self, quaternion: np.ndarray | None, accel: np.ndarray | None) -> bool:
        """Start from the IMU's orientation output, else from gravity with zero yaw.

        Returns whether it could (it needs one of the two)."""
        if quaternion is not None:
            q = tuple(float(c) for c in quaternion)
        elif accel is not None and np.linalg.norm(accel) > 0.5 * GRAVITY:
            q = tuple(float(c) for c in so3.matrix_to_quat(_tilt_from_gravity(np.asarray(accel, float))))
        else:
            return False
        self._q = _normalized(q)
        self._bias = (0.0, 0.0, 0.0)
        self.initialized = True
        return True

    def update(
        self, gyro: Sequence[float], dt: float, quaternion: Sequence[float] | None, accel: Sequence[float] | None
    ) -> None:
        """Propagate with the gyro (IMU frame, rad/s) over ``dt`` and correct toward the IMU's
        orientation output ``quaternion`` or, without it, toward the gravity direction of ``accel``
        (arrays, or sequences of Python floats: the cheapest)."""
        x, y, z, w = self._q
        bx, by, bz = self._bias
        ex = ey = ez = 0.0
        gain = 0.0
        if quaternion is not None:
            # Body-frame error rotation conj(q) * q_measured; 2 * its vector part ~ rotation vector.
            mx, my, mz, mw = so3.as_floats(quaternion)
            ew = w * mw + x * mx + y * my + z * mz
            sign = 2.0 if ew >= 0.0 else -2.0
            ex = sign * (w * mx - x * mw - y * mz + z * my)
            ey = sign * (w * my + x * mz - y * mw - z * mx)
            ez = sign * (w * mz - x * my + y * mx - z * mw)
            gain = self.orientation_gain
        elif accel is not None:
            ax, ay, az = so3.as_floats(accel)
            norm = math.sqrt(ax * ax + ay * ay + az * az)
            trust = max(0.0, 1.0 - abs(norm - GRAVITY) / (0.1 * GRAVITY))  # 0 beyond +-10 % of 1 g
            if trust > 0.0:
                ux, uy, uz = ax / norm, ay / norm, az / norm  # measured up, IMU frame
                # Estimated up: world z in the IMU frame, the third row of R(q).
                vx, vy, vz = 2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)
                ex, ey, ez = trust * (uy * vz - uz * vy), trust * (uz * vx - ux * vz), trust * (ux * vy - uy * vx)
                gain = self.accel_gain
        if gain > 0.0:
            step, limit = self.bias_gain * dt, self.max_bias
            bx = min(limit, max(-limit, bx - step * ex))
            by = min(limit, max(-limit, by - step * ey))
            bz = min(limit, max(-limit, bz - step * ez))
            self._bias = (bx, by, bz)
        gx, gy, gz = so3.as_floats(gyro)
        rx, ry, rz = (gx - bx + gain * ex) * dt, (gy - by + gain * ey) * dt, (gz - bz + gain * ez) * dt
        angle = math.sqrt(rx * rx + ry * ry + rz * rz)
        half = 0.5 * angle
        s = 0.5 - angle * angle / 48.0 if angle < 1e-4 else math.sin(half) / angle  # sin(angle/2) / angle
        dx, dy, dz, dw = s * rx, s * ry, s * rz, math.cos(half)
        self._q = _normalized(
            (
                w * dx + x * dw + y * dz - z * dy,
                w * dy - x * dz + y * dw + z * dx,
                w * dz + x * dy - y * dx + z * dw,
                w * dw - x * dx - y * dy - z * dz,
            )
        )

    def angular_velocity(self, gyro: np.ndarray) -> np.ndarray:
        """Bias-corrected angular velocity, IMU frame."""
        return np.asarray(gyro, float) - self._bias


def _normalized(q: tuple[float, ...]) -> tuple[float, float, float, float]:
    x, y, z, w = q
    n = 1.0 / math.sqrt(x * x + y * y + z * z + w * w)
    if w < 0.0:
        n = -n
    return (x * n, y * n, z * n, w * n)


def _tilt_from_gravity(accel: np.ndarray) -> np.ndarray:
    """Rotation with zero yaw whose world z axis, seen in the IMU frame, is along ``accel``."""
    up = accel / np.linalg.norm(accel)  # world z in the IMU frame = third row of R
    x_axis = np.array([1.0, 0.0, 0.0]) - up[0] * up  # IMU x projected off the vertical
    if np.linalg.norm(x_axis) < 1e-6:
        x_axis = np.array([0.0, 1.0, 0.0]) - up[1] * up
    x_axis /= np.linalg.norm(x_axis)
    # Rows of R (world axes in the IMU frame): z = up, x = heading (yaw 0), y = z cross x.
    return np.vstack([x_axis, np.cross(up, x_axis), up])
