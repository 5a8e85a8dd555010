"""IMU orientation: a complementary filter on SO(3) with gyro-bias estimation (Mahony's PI form).

The gyro propagates the orientation at full rate; slow, drift-free references pull it back
through a proportional correction, whose integral estimates the gyro bias. References, best first
(the estimator picks one per update, :meth:`OrientationFilter.correct` takes its error):

* flat feet in stance (tilt and heading from the joint encoders, :mod:`~giwbc.estimation.estimator`);
* the IMU's own orientation output when it has one (its AHRS fuses gravity and, for yaw, whatever
  it uses);
* the accelerometer's gravity direction (roll and pitch only), trusted only while the specific
  force, less the acceleration the legs measure, is close to 1 g.

Anti-windup: the bias integral runs only while the error is below ``integral_window`` (a large
start-up or push error is corrected by the proportional term alone, so the integral does not
wind up on it), and each reference has an integral gain that keeps its loop at least critically
damped (``bias_gain <= gain^2 / 4``), so no error overshoots.

The filter keeps a unit quaternion in plain Python floats: per update it is a few dozen scalar
operations, far cheaper than numpy calls on 3-vectors.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from giwbc.robot import so3

__all__ = ["OrientationFilter", "gravity_error", "quaternion_error", "tilt_from_gravity"]

GRAVITY = 9.81


class OrientationFilter:
    """Orientation of one IMU in the world (``quaternion`` xyzw, ``rotation``) and its gyro bias.

    Gains are rates: ``orientation_gain`` (1/s) pulls toward the IMU's orientation output,
    ``accel_gain`` (1/s) toward the accelerometer's gravity direction, ``bias_gain`` (1/s^2)
    integrates the orientation-output correction into the bias (the accelerometer's integral gain
    is ``accel_gain^2 / 4``: critically damped), clamped to ``max_bias`` (rad/s) per axis, and only
    while the error is below ``integral_window`` (rad).
    """

    def __init__(
        self,
        orientation_gain: float = 2.0,
        accel_gain: float = 0.5,
        bias_gain: float = 0.2,
        max_bias: float = 0.1,
        integral_window: float = math.radians(2.0),
    ) -> None:
        self.orientation_gain = orientation_gain
        self.accel_gain = accel_gain
        self.bias_gain = bias_gain
        self.accel_bias_gain = 0.25 * accel_gain * accel_gain
        self.max_bias = max_bias
        self.integral_window = integral_window
        self.initialized = False
        self._q = (0.0, 0.0, 0.0, 1.0)
        self._bias = (0.0, 0.0, 0.0)
        self._rate = (0.0, 0.0, 0.0)  # proportional correction (IMU frame, rad/s) applied by the next propagation

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
            q = tuple(float(c) for c in so3.matrix_to_quat(tilt_from_gravity(np.asarray(accel, float))))
        else:
            return False
        self.reset_to(q, (0.0, 0.0, 0.0))
        return True

    def reset_to(self, quaternion: Sequence[float], gyro_bias: Sequence[float]) -> None:
        """Start from a known orientation and gyro bias (a calibration)."""
        self._q = _normalized(tuple(float(c) for c in quaternion))
        self.set_gyro_bias(gyro_bias)
        self._rate = (0.0, 0.0, 0.0)
        self.initialized = True

    def set_gyro_bias(self, gyro_bias: Sequence[float]) -> None:
        """Replace the bias estimate (a standstill measurement of it), clamped to ``max_bias``."""
        limit = self.max_bias
        self._bias = tuple(min(limit, max(-limit, float(b))) for b in gyro_bias)  # type: ignore[assignment]

    # --- the filter -----------------------------------------------------------------------
    def update(
        self, gyro: Sequence[float], dt: float, quaternion: Sequence[float] | None, accel: Sequence[float] | None
    ) -> None:
        """Correct toward the IMU's orientation output ``quaternion`` or, without it, toward the
        gravity direction of ``accel`` (IMU frame), then propagate with the gyro (IMU frame,
        rad/s) over ``dt``."""
        if quaternion is not None:
            self.correct(quaternion_error(self._q, quaternion), self.orientation_gain, self.bias_gain, dt)
        elif accel is not None:
            self.correct(gravity_error(self._q, accel), self.accel_gain, self.accel_bias_gain, dt)
        else:
            self._rate = (0.0, 0.0, 0.0)
        self.propagate(gyro, dt)

    def correct(self, error: Sequence[float] | None, gain: float, bias_gain: float, dt: float) -> None:
        """Set the correction toward a reference: ``error`` is the rotation vector (IMU frame)
        from the estimate to the reference (None: no reference this update). The proportional
        part is applied by the next :meth:`propagate`; the integral moves the bias now."""
        if error is None or gain <= 0.0:
            self._rate = (0.0, 0.0, 0.0)
            return
        ex, ey, ez = error
        window = self.integral_window
        if bias_gain > 0.0 and ex * ex + ey * ey + ez * ez < window * window:
            bx, by, bz = self._bias
            step, limit = bias_gain * dt, self.max_bias
            self._bias = (
                min(limit, max(-limit, bx - step * ex)),
                min(limit, max(-limit, by - step * ey)),
                min(limit, max(-limit, bz - step * ez)),
            )
        self._rate = (gain * ex, gain * ey, gain * ez)

    def propagate(self, gyro: Sequence[float], dt: float) -> None:
        """Integrate the bias-corrected gyro (IMU frame, rad/s) plus the pending correction over ``dt``."""
        x, y, z, w = self._q
        bx, by, bz = self._bias
        cx, cy, cz = self._rate
        gx, gy, gz = so3.as_floats(gyro)
        rx, ry, rz = (gx - bx + cx) * dt, (gy - by + cy) * dt, (gz - bz + cz) * dt
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


def quaternion_error(q: Sequence[float], measured: Sequence[float]) -> tuple[float, float, float]:
    """Rotation vector (body frame) from orientation ``q`` to ``measured``: 2 x the vector part of
    ``conj(q) * measured`` (small angles)."""
    x, y, z, w = q
    mx, my, mz, mw = so3.as_floats(measured)
    ew = w * mw + x * mx + y * my + z * mz
    sign = 2.0 if ew >= 0.0 else -2.0
    return (
        sign * (w * mx - x * mw - y * mz + z * my),
        sign * (w * my + x * mz - y * mw - z * mx),
        sign * (w * mz - x * my + y * mx - z * mw),
    )


def gravity_error(q: Sequence[float], up: Sequence[float], tolerance: float = 0.1) -> tuple[float, float, float] | None:
    """Rotation vector (body frame) that turns the estimated up direction (world z seen from
    orientation ``q``) toward the measured one ``up`` (a specific force, body frame), weighted by
    how close ``|up|`` is to 1 g (0 beyond ``tolerance`` of it: then None)."""
    ax, ay, az = so3.as_floats(up)
    norm = math.sqrt(ax * ax + ay * ay + az * az)
    trust = 1.0 - abs(norm - GRAVITY) / (tolerance * GRAVITY) if norm > 0.0 else 0.0
    if trust <= 0.0:
        return None
    x, y, z, w = q
    ux, uy, uz = ax / norm, ay / norm, az / norm  # measured up, body frame
    vx, vy, vz = 2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)  # estimated up: R(q)[2, :]
    return trust * (uy * vz - uz * vy), trust * (uz * vx - ux * vz), trust * (ux * vy - uy * vx)


def _normalized(q: tuple[float, ...]) -> tuple[float, float, float, float]:
    x, y, z, w = q
    n = 1.0 / math.sqrt(x * x + y * y + z * z + w * w)
    if w < 0.0:
        n = -n
    return (x * n, y * n, z * n, w * n)


def tilt_from_gravity(up: np.ndarray, yaw: float = 0.0) -> np.ndarray:
    """Rotation (body in world) with heading ``yaw`` whose world z axis, seen in the body frame,
    is along ``up`` (e.g. a specific force at rest)."""
    up = np.asarray(up, float) / np.linalg.norm(up)  # world z in the body frame = third row of R
    x_axis = np.array([1.0, 0.0, 0.0]) - up[0] * up  # body x projected off the vertical
    if np.linalg.norm(x_axis) < 1e-6:
        x_axis = np.array([0.0, 1.0, 0.0]) - up[1] * up
    x_axis /= np.linalg.norm(x_axis)
    # Rows of R (world axes in the body frame): z = up, x = heading (yaw 0), y = z cross x.
    level = np.vstack([x_axis, np.cross(up, x_axis), up])
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ level
