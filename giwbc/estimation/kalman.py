"""A linear Kalman filter fusing IMU acceleration with leg kinematics (the legged-robot classic).

State (world frame): IMU position, IMU velocity, and one point per foot (its sole centre).
Process: the IMU acceleration (rotated to world, gravity removed) drives position and velocity;
feet stand still up to a small slip noise in stance and move freely (large noise) in swing.
Measurements, per foot, from encoders: the foot's position relative to the IMU, and, in stance,
the foot's velocity relative to the IMU (which is minus the IMU velocity for a foot that does not
move); optionally the foot height on flat ground. A stance foot is weighted by a confidence in (0, 1]
(its load): its velocity noise and slip noise grow as the confidence drops, and a foot whose
velocity contradicts the IMU-propagated one beyond a chi-square gate (slip, impact) has its
velocity noise scaled by the excess (a robust update).

Every model matrix acts on the x, y and z axes separately (``F``, ``H`` and the noises are
``(.) kron I3``), so the filter runs as three small filters of ``2 + n_feet`` states
(``x[axis]``): the same estimate as the 3(2 + n_feet)-state filter at a fraction of the cost.
Axes with the same measurement rows have the same covariance at all times (it starts equal and sees
the same process and measurement noise): x and y, and z too unless foot heights are measured. Each such group of axes keeps one covariance and one gain, so
the default filter updates a single ``(2 + n_feet)``-square covariance per sample. The size is
fixed: a missing measurement (a swing foot's velocity, a leg with bad encoders) gets a zero row
in ``H`` and a zero residual, which carries no information, so arrays stay the same shape and
every update costs the same.

The filter runs once per control tick on matrices of a few rows, where each numpy call costs more
than its arithmetic: work arrays are allocated once and updated in place, and per-foot scalars
are plain floats.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from giwbc.robot.so3 import as_floats

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


class _AxisGroup:
    """Axes ``axes`` (a slice of x, y, z) sharing measurement rows ``H`` and so one covariance ``P``."""

    def __init__(self, axes: slice, H: np.ndarray) -> None:
        rows, states = H.shape
        self.axes = axes
        self.rows = rows
        self.H_full = H
        self.H = H.copy()  # H_full with the rows of missing measurements zeroed
        self.P = np.eye(states)
        self.P_diagonal = self.P.reshape(-1)[:: states + 1]  # a view
        self.S = np.zeros((rows, rows))
        self.S_diagonal = self.S.reshape(-1)[:: rows + 1]  # a view
        # For base_covariance: entry (3 i + a, 3 j + a) of the (6, 6) matrix is P[i, j] (i, j < 2)
        # for each axis a of the group, as flat indices into both.
        pairs = [(axis, i, j) for axis in range(axes.start, axes.stop) for i in (0, 1) for j in (0, 1)]
        self.cov_index = np.array([(3 * i + axis) * 6 + 3 * j + axis for axis, i, j in pairs])
        self.cov_source = np.array([i * states + j for _, i, j in pairs])


class LegKalmanFilter:
    """Per axis ``a``: ``x[a] = [p_imu, v_imu, p_foot_0, ..., p_foot_n-1]``; ``P`` its covariance
    (``P[a]``, a copy: axes share theirs as the module says)."""

    def __init__(
        self, n_feet: int, noise: LegKalmanNoise | None = None, use_ground_height: bool = False, velocity_gate: float = 11.3,
        gate_power: float = 1.0,
    ) -> None:
        self.noise = noise if noise is not None else LegKalmanNoise()
        self.velocity_gate = velocity_gate  # normalized innovation above which a foot's velocity is down-weighted
        self.gate_power = gate_power  # ... its variance times (innovation / gate)^power: 1 Huber-like, 2 a slipping foot left out
        self.n_feet = n = n_feet
        self.use_ground_height = use_ground_height
        states = 2 + n
        self.x = np.zeros((3, states))
        H = np.zeros(((3 if use_ground_height else 2) * n, states))  # rows: foot positions, stance velocities, ground heights
        for i in range(n):
            H[i, 0], H[i, 2 + i] = -1.0, 1.0  # foot - imu position
            H[n + i, 1] = -1.0  # foot velocity relative to the IMU = -imu velocity (a stance foot is still)
            if use_ground_height:
                H[2 * n + i, 2 + i] = 1.0  # foot height (z axis only)
        if use_ground_height:
            self._groups = (_AxisGroup(slice(0, 2), H[: 2 * n].copy()), _AxisGroup(slice(2, 3), H))
        else:
            self._groups = (_AxisGroup(slice(0, 3), H),)
        self._axis_groups = tuple(g for g in self._groups for _ in range(g.axes.start, g.axes.stop))  # per axis
        self._z = np.zeros((3, len(H)))
        variances = np.ones(len(H))
        variances[:n] = self.noise.foot_position**2
        variances[2 * n :] = self.noise.ground_height**2
        self._variances = variances  # measurement noise per row (velocity rows set per update)
        self._corrections = 0

    @property
    def P(self) -> np.ndarray:
        """Covariance per axis, (3, 2 + n_feet, 2 + n_feet) (a copy)."""
        return np.array([group.P for group in self._axis_groups])

    def initialize(
        self, imu_position: np.ndarray, foot_positions: np.ndarray, position_std: float = 0.01, velocity_std: float = 0.05
    ) -> None:
        """Start at rest at ``imu_position`` with feet at ``foot_positions`` (world, (n_feet, 3))."""
        self.x[:] = 0.0
        self.x[:, 0] = imu_position
        self.x[:, 2:] = np.asarray(foot_positions, float).T
        variances = np.full(2 + self.n_feet, position_std**2)
        variances[1] = velocity_std**2
        for group in self._groups:
            group.P[:] = np.diag(variances)
        self._corrections = 0  # P is symmetrized every 16 corrections: counted from the start, as in a new filter

    def predict(self, acceleration: Sequence[float] | None, dt: float, stance: Sequence[float]) -> None:
        """Propagate over ``dt`` with the IMU's world acceleration (``None``: unknown, assume 0).

        ``stance``: per foot, 0 for swing, else the confidence (0, 1] that it stands still; a
        stance foot's slip noise grows as its confidence drops, up to the swing noise."""
        noise, x = self.noise, self.x
        ax, ay, az = (0.0, 0.0, 0.0) if acceleration is None else acceleration
        half_dt2 = 0.5 * dt * dt
        (px, vx), (py, vy), (pz, vz) = x[:, :2].tolist()  # plain floats: cheaper than numpy on 3-vectors
        x[:, :2] = (
            (px + (vx * dt + half_dt2 * ax), vx + ax * dt),
            (py + (vy * dt + half_dt2 * ay), vy + ay * dt),
            (pz + (vz * dt + half_dt2 * az), vz + az * dt),
        )
        # Q is diagonal: position, velocity (acceleration noise), then each foot's slip.
        stance_std, swing_std = noise.stance_foot, noise.swing_foot
        acceleration_std = noise.acceleration if acceleration is not None else noise.missing_acceleration
        process = [noise.position**2 * dt, acceleration_std**2 * dt]
        for confidence in as_floats(stance):
            std = min(stance_std / max(confidence, 1e-6), swing_std)
            process.append(std * std * dt)
        for group in self._groups:
            # F P F^T with F = I + dt e_0 e_1^T (position += dt velocity): a row, then a column operation.
            P = group.P
            P[0] += dt * P[1]
            P[:, 0] += dt * P[:, 1]
            group.P_diagonal += process

    def correct(
        self,
        foot_positions: np.ndarray,
        foot_velocities: np.ndarray,
        stance: Sequence[float],
        position_valid: np.ndarray,
        velocity_valid: np.ndarray,
        ground_height: float = 0.0,
    ) -> None:
        """Fuse per-foot kinematics: ``foot_positions`` relative to the IMU, ``foot_velocities``
        relative to a non-translating IMU (world axes, (n_feet, 3)). ``stance`` as in
        :meth:`predict`: velocity (and ground height) rows count for stance feet only, their
        noise scaled by 1 / confidence; invalid legs are left out."""
        n, z = self.n_feet, self._z
        confidences = as_floats(stance)
        z[:, :n] = foot_positions.T
        z[:, n : 2 * n] = foot_velocities.T
        positions_used = position_valid.tolist()
        velocities_used = [c > 0.0 and ok for c, ok in zip(confidences, velocity_valid.tolist())]
        used = positions_used + velocities_used
        if self.use_ground_height:
            z[2, 2 * n :] = ground_height
            used += [c > 0.0 and ok for c, ok in zip(confidences, positions_used)]
        everything = all(used)
        if not everything:
            z[:, np.logical_not(used)] = 0.0
        self._variances[n : 2 * n] = self._velocity_variances(confidences, foot_velocities)
        for group in self._groups:
            H = group.H_full
            if not everything:
                H = group.H
                np.multiply(group.H_full, np.array(used[: group.rows])[:, None], out=H)
            self._correct_group(group, H, z[group.axes, : group.rows])
        self._corrections += 1
        if self._corrections % 16 == 0:  # keep P symmetric against rounding
            for group in self._groups:
                group.P[:] = 0.5 * (group.P + group.P.T)

    def _correct_group(self, group: _AxisGroup, H: np.ndarray, z: np.ndarray) -> None:
        """The Kalman update of ``group``'s axes with measurements ``z`` (axes, rows)."""
        x, P = self.x[group.axes], group.P  # x: a view
        residual = z - x @ H.T
        HP = H @ P
        np.matmul(HP, H.T, out=group.S)
        group.S_diagonal += self._variances[: group.rows]
        *_, gain_t, info = lapack.dgesv(group.S, HP)  # K^T = S^-1 H P (S symmetric)
        if info != 0:
            raise np.linalg.LinAlgError("singular innovation covariance")
        x += residual @ gain_t
        P -= gain_t.T @ HP

    def _velocity_variances(self, confidences: list[float], foot_velocities: np.ndarray) -> list[float]:
        """Noise variance of each foot's velocity row: the encoder noise over the squared
        confidence, scaled by the normalized innovation beyond the gate (a foot that slips or
        bounces contradicts the IMU-propagated velocity: a Huber-like robust update).
        Plain floats: a few per foot."""
        base, gate, power = self.noise.foot_velocity**2, self.velocity_gate, self.gate_power
        vx, vy, vz = self.x[:, 1].tolist()
        px, py, pz = (group.P.item(1, 1) for group in self._axis_groups)  # IMU velocity variance per axis
        variances = []
        for confidence, (fx, fy, fz) in zip(confidences, foot_velocities.tolist()):
            confidence = max(confidence, 1e-3)
            variance = base / (confidence * confidence)
            if gate > 0:
                rx, ry, rz = fx + vx, fy + vy, fz + vz  # innovation: the foot's velocity + the IMU's (zero if still)
                nis = rx * rx / (px + variance) + ry * ry / (py + variance) + rz * rz / (pz + variance)
                if nis > gate:
                    variance *= nis / gate if power == 1.0 else (nis / gate) ** power
            variances.append(variance)
        return variances

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
        flat = covariance.reshape(-1)
        for group in self._groups:
            flat[group.cov_index] = group.P.reshape(-1)[group.cov_source]
        return covariance

