"""A linear Kalman filter fusing IMU acceleration with leg kinematics (the legged-robot classic).

State (world frame): IMU position, IMU velocity, and one point per foot (its sole centre).
Process: the IMU acceleration (rotated to world, gravity removed) drives position and velocity;
feet stand still up to a small slip noise in stance and move freely (large noise) in swing.
Measurements, per foot, from encoders: the foot's position relative to the IMU, and, in stance,
the IMU velocity implied by a foot that does not move; optionally the foot height on flat ground.
A stance foot is weighted by a confidence in (0, 1] (its load): its velocity noise and slip noise
grow as the confidence drops, and a foot whose velocity contradicts the IMU-propagated one beyond
a chi-square gate (slip, impact) has its velocity noise scaled by the excess (a robust update).

Every model matrix acts on the x, y and z axes separately (``F``, ``H`` and the noises are
``(.) kron I3``), so the filter runs as three small filters of ``2 + n_feet`` states batched in
one array (``x[axis]``, ``P[axis]``): the same estimate as the 3(2 + n_feet)-state filter at a
fraction of the cost. The size is fixed: a missing measurement (a swing foot's velocity, a leg
with bad encoders) gets a zero row in ``H`` and a zero residual, which carries no information,
so arrays stay the same shape and every update costs the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LegKalmanFilter", "LegKalmanNoise"]

GRAVITY = np.array([0.0, 0.0, -9.81])


@dataclass(frozen=True)
class LegKalmanNoise:
    """Standard deviations: process densities per sqrt(s), measurements per sample."""

    acceleration: float = 0.3  # m/s^2/sqrt(Hz): accelerometer noise, bias and tilt leakage
    missing_acceleration: float = 10.0  # m/s^2/sqrt(Hz): when the accelerometer is unusable
    position: float = 1e-3  # m/sqrt(s): IMU position beyond what velocity explains
    stance_foot: float = 2e-3  # m/sqrt(s): slip of a stance foot
    swing_foot: float = 2.0  # m/sqrt(s): a swing foot goes where its leg takes it
    foot_position: float = 5e-3  # m: kinematic foot position (encoder noise, model error)
    foot_velocity: float = 0.05  # m/s: kinematic velocity of a stance foot (encoder velocity noise)
    ground_height: float = 0.01  # m: stance foot height on flat ground (when used)

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not value > 0:
                raise ValueError(f"LegKalmanNoise.{name} must be > 0, got {value!r}")


class LegKalmanFilter:
    """Per axis ``a``: ``x[a] = [p_imu, v_imu, p_foot_0, ..., p_foot_n-1]`` and covariance ``P[a]``."""

    def __init__(
        self, n_feet: int, noise: LegKalmanNoise | None = None, use_ground_height: bool = False, velocity_gate: float = 11.3
    ) -> None:
        self.noise = noise if noise is not None else LegKalmanNoise()
        self.velocity_gate = velocity_gate  # normalized innovation above which a foot's velocity is down-weighted
        self.n_feet = n = n_feet
        self.use_ground_height = use_ground_height
        states, rows = 2 + n, (3 if use_ground_height else 2) * n
        self.x = np.zeros((3, states))
        self.P = np.tile(np.eye(states), (3, 1, 1))
        self._F = np.eye(states)
        self._Q = np.zeros((states, states))
        self._H_full = np.zeros((3, rows, states))  # rows: foot positions, stance velocities, ground heights
        for i in range(n):
            self._H_full[:, i, 0], self._H_full[:, i, 2 + i] = -1.0, 1.0  # foot - imu position
            self._H_full[:, n + i, 1] = 1.0  # imu velocity (a stance foot is still)
            if use_ground_height:
                self._H_full[2, 2 * n + i, 2 + i] = 1.0  # foot height (z axis only)
        self._H = self._H_full.copy()
        self._z = np.zeros((3, rows))
        variances = np.ones(rows)
        variances[:n] = self.noise.foot_position**2
        variances[n : 2 * n] = self.noise.foot_velocity**2
        variances[2 * n :] = self.noise.ground_height**2
        self._variances = variances  # measurement noise per row (velocity rows rescaled per update)
        self._rows = np.arange(rows)
        self._corrections = 0
        self._cov_index = (np.array([0, 1, 2, 3, 4, 5, 0, 1, 2, 3, 4, 5]), np.array([0, 1, 2, 3, 4, 5, 3, 4, 5, 0, 1, 2]))

    def initialize(
        self, imu_position: np.ndarray, foot_positions: np.ndarray, position_std: float = 0.01, velocity_std: float = 0.05
    ) -> None:
        """Start at rest at ``imu_position`` with feet at ``foot_positions`` (world, (n_feet, 3))."""
        self.x[:] = 0.0
        self.x[:, 0] = imu_position
        self.x[:, 2:] = np.asarray(foot_positions, float).T
        variances = np.full(2 + self.n_feet, position_std**2)
        variances[1] = velocity_std**2
        self.P[:] = np.diag(variances)

    def predict(self, acceleration: np.ndarray | None, dt: float, stance: np.ndarray) -> None:
        """Propagate over ``dt`` with the IMU's world acceleration (``None``: unknown, assume 0).

        ``stance``: per foot, 0 for swing, else the confidence (0, 1] that it stands still; a
        stance foot's slip noise grows as its confidence drops, up to the swing noise."""
        noise, x, F, Q = self.noise, self.x, self._F, self._Q
        if acceleration is not None:
            x[:, 0] += x[:, 1] * dt + (0.5 * dt * dt) * acceleration
            x[:, 1] += acceleration * dt
        else:
            x[:, 0] += x[:, 1] * dt
        F[0, 1] = dt
        Q[0, 0] = noise.position**2 * dt
        Q[1, 1] = (noise.acceleration if acceleration is not None else noise.missing_acceleration) ** 2 * dt
        diagonal = Q.reshape(-1)[2 * (len(Q) + 1) :: len(Q) + 1]  # feet entries of Q's diagonal (a view)
        foot_std = np.minimum(noise.stance_foot / np.maximum(stance, 1e-6), noise.swing_foot)
        diagonal[:] = foot_std * foot_std * dt
        self.P = F @ self.P @ F.T + Q

    def correct(
        self,
        foot_positions: np.ndarray,
        foot_velocities: np.ndarray,
        stance: np.ndarray,
        position_valid: np.ndarray,
        velocity_valid: np.ndarray,
        ground_height: float = 0.0,
    ) -> None:
        """Fuse per-foot kinematics: ``foot_positions`` relative to the IMU, ``foot_velocities``
        relative to a non-translating IMU (world axes, (n_feet, 3)). ``stance`` as in
        :meth:`predict`: velocity (and ground height) rows count for stance feet only, their
        noise scaled by 1 / confidence; invalid legs are left out."""
        n, H, z, noise = self.n_feet, self._H, self._z, self.noise
        z[:, :n] = foot_positions.T
        z[:, n : 2 * n] = -foot_velocities.T
        standing = stance > 0.0
        used = [position_valid, standing & velocity_valid]
        if self.use_ground_height:
            z[2, 2 * n :] = ground_height
            used.append(standing & position_valid)
        used_rows = np.concatenate(used)
        if used_rows.all():
            H = self._H_full
        else:
            np.multiply(self._H_full, used_rows[:, None], out=H)
            z[:, ~used_rows] = 0.0
        variances = self._variances
        velocity_variances = noise.foot_velocity**2 / np.maximum(stance, 1e-3) ** 2
        if self.velocity_gate > 0:
            # A foot that slips or bounces contradicts the IMU-propagated velocity: scale its
            # noise by its normalized innovation beyond the gate (a Huber-like robust update).
            innovation = z[:, n : 2 * n] - self.x[:, 1:2]
            nis = (innovation * innovation / (self.P[:, 1, 1][:, None] + velocity_variances)).sum(axis=0)
            velocity_variances *= np.maximum(1.0, nis / self.velocity_gate)
        variances[n : 2 * n] = velocity_variances
        HP = H @ self.P
        S = HP @ H.transpose(0, 2, 1)
        S[:, self._rows, self._rows] += variances
        gain_t = np.linalg.solve(S, HP)  # K^T = S^-1 H P per axis (S symmetric)
        residual = z - (H @ self.x[:, :, None])[:, :, 0]
        self.x += (residual[:, None, :] @ gain_t)[:, 0, :]
        self.P = self.P - gain_t.transpose(0, 2, 1) @ HP
        self._corrections += 1
        if self._corrections % 16 == 0:  # keep P symmetric against rounding
            self.P = 0.5 * (self.P + self.P.transpose(0, 2, 1))

    @property
    def imu_position(self) -> np.ndarray:
        return self.x[:, 0].copy()

    @property
    def imu_velocity(self) -> np.ndarray:
        return self.x[:, 1].copy()

    @property
    def foot_positions(self) -> np.ndarray:
        """World position of each foot's sole centre, (n_feet, 3)."""
        return self.x[:, 2:].T.copy()

    def base_covariance(self) -> np.ndarray:
        """Covariance (6, 6) of ``[p_imu, v_imu]`` (world; the axes are independent)."""
        covariance = np.zeros((6, 6))
        P = self.P
        covariance[self._cov_index] = np.concatenate([P[:, 0, 0], P[:, 1, 1], P[:, 0, 1], P[:, 1, 0]])
        return covariance
