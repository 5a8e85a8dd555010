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

The filter runs once per control tick on matrices of a few rows, where each numpy call would cost
more than its arithmetic: a prediction and a correction are one compiled call each
(:func:`giwbc.estimation.kernels.kalman_predict`, :func:`~giwbc.estimation.kernels.kalman_correct`)
on arrays allocated once and updated in place.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from giwbc.estimation import kernels

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
    """Axes ``axes`` (a slice of x, y, z) sharing measurement rows (their number: ``rows``) and so one
    covariance ``P`` (a view of the filter's stacked covariances)."""

    def __init__(self, axes: slice, rows: int, P: np.ndarray) -> None:
        states = P.shape[0]
        self.axes = axes
        self.rows = rows
        self.P = P
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
        groups = ((slice(0, 2), 2 * n), (slice(2, 3), 3 * n)) if use_ground_height else ((slice(0, 3), 2 * n),)
        self._P = np.zeros((len(groups), states, states))  # per group
        self._H = np.zeros((len(groups), len(H), states))  # per group, its rows first
        for g, (_, rows) in enumerate(groups):
            self._H[g, :rows] = H[:rows]
            self._P[g] = np.eye(states)
        self._group_rows = np.array([rows for _, rows in groups], dtype=np.int64)
        self._group_axes = np.array([(axes.start, axes.stop) for axes, _ in groups], dtype=np.int64)
        self._groups = tuple(_AxisGroup(axes, rows, self._P[g]) for g, (axes, rows) in enumerate(groups))
        self._axis_groups = tuple(g for g in self._groups for _ in range(g.axes.start, g.axes.stop))  # per axis
        self._z = np.zeros((3, len(H)))
        self._used = np.ones(len(H), dtype=np.bool_)
        variances = np.ones(len(H))
        variances[:n] = self.noise.foot_position**2
        variances[2 * n :] = self.noise.ground_height**2
        self._variances = variances  # measurement noise per row (velocity rows set per update)
        noise = self.noise
        self._process_noise = np.array([noise.acceleration, noise.missing_acceleration, noise.position, noise.stance_foot,
                                        noise.swing_foot])
        self._acceleration = np.zeros(3)
        self._stance = np.zeros(n)
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
        known = acceleration is not None
        if known:
            self._acceleration[:] = acceleration
        self._stance[:] = stance
        kernels.kalman_predict(self.x, self._P, self._acceleration, known, dt, self._stance, self._process_noise)

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
        self._stance[:] = stance
        corrections = kernels.kalman_correct(
            self.x, self._P, self._H, self._group_rows, self._group_axes, self._z, self._used, self._variances, self._stance,
            foot_positions, foot_velocities, position_valid, velocity_valid, float(ground_height), self.noise.foot_velocity**2,
            self.velocity_gate, self.gate_power, self._corrections,
        )
        if corrections < 0:
            raise np.linalg.LinAlgError("singular innovation covariance")
        self._corrections = corrections

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

