"""Swing-foot trajectories: lift-off to touch-down over an apex, re-targetable in flight.

Each coordinate (x, y, z, yaw) is a chain of quintic polynomials, each matching position,
velocity and acceleration at both of its ends, so the trajectory is C² — continuous in position,
velocity and acceleration — and at rest (zero velocity and acceleration) at lift-off and at
touch-down. z rises to the apex height at the apex time, with zero vertical velocity there.

:meth:`SwingTrajectory.retarget` moves the landing spot and/or the touch-down time *during* the
swing: from the current state (position, velocity, acceleration at that instant) new quintics
reach the new target, so nothing jumps (the step adapter re-targets every tick).
"""

from __future__ import annotations

import math

import numpy as np

from giwbc.locomotion.kernels import SWING_COLUMNS, swing_state


def quintic(t0: float, t1: float, start: tuple[float, float, float], end: tuple[float, float, float]) -> np.ndarray:
    """Coefficients (6,) in ``s = t − t0`` of the quintic with the given (position, velocity,
    acceleration) at ``t0`` and ``t1``."""
    return np.array(_quintic(t0, t1, start, end))


def _quintic(t0: float, t1: float, start: tuple[float, float, float], end: tuple[float, float, float]) -> tuple[float, ...]:
    """:func:`quintic`'s coefficients as plain floats (a swing is re-targeted at many ticks:
    the same operations on the same values, without numpy)."""
    T = t1 - t0
    if not T > 0:
        raise ValueError(f"a quintic needs t1 > t0, got {t0}, {t1}")
    p0, v0, a0 = (float(x) for x in start)
    p1, v1, a1 = (float(x) for x in end)
    T2, T3, T4, T5 = T * T, T**3, T**4, T**5
    c3 = (20 * (p1 - p0) - (8 * v1 + 12 * v0) * T - (3 * a0 - a1) * T2) / (2 * T3)
    c4 = (-30 * (p1 - p0) + (14 * v1 + 16 * v0) * T + (3 * a0 - 2 * a1) * T2) / (2 * T4)
    c5 = (12 * (p1 - p0) - 6 * (v1 + v0) * T - (a0 - a1) * T2) / (2 * T5)
    return (p0, v0, a0 / 2.0, float(c3), float(c4), float(c5))


def _evaluate(coefficients: tuple[float, ...] | np.ndarray, s: float) -> tuple[float, float, float]:
    c0, c1, c2, c3, c4, c5 = coefficients
    p = c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))))
    v = c1 + s * (2 * c2 + s * (3 * c3 + s * (4 * c4 + s * 5 * c5)))
    a = 2 * c2 + s * (6 * c3 + s * (12 * c4 + s * 20 * c5))
    return float(p), float(v), float(a)


class _Chain:
    """A sequence of quintics (coefficient tuples, :func:`_quintic`) over consecutive time
    intervals; constant outside them."""

    def __init__(self, knots: list[float], pieces: list[tuple[float, ...]]) -> None:
        self.knots, self._floats = knots, pieces  # (evaluated every tick: no numpy scalars)

    def __call__(self, t: float) -> tuple[float, float, float]:
        knots, pieces = self.knots, self._floats
        if t < knots[0]:
            return _evaluate(pieces[0], 0.0)[0], 0.0, 0.0
        for i, piece in enumerate(pieces):
            if t <= knots[i + 1]:
                return _evaluate(piece, t - knots[i])
        return _evaluate(pieces[-1], knots[-1] - knots[-2])[0], 0.0, 0.0


class SwingTrajectory:
    """A sole's swing from ``start`` (x, y, z, yaw) at ``t0`` to ``target`` at ``t1`` over
    ``apex`` m above the higher of the two ends, at the middle of the swing."""

    def __init__(self, t0: float, t1: float, start: np.ndarray, target: np.ndarray, apex: float = 0.08, apex_fraction: float = 0.5) -> None:
        start = np.asarray(start, dtype=float).reshape(4)
        target = np.asarray(target, dtype=float).reshape(4)
        if not (np.all(np.isfinite(start)) and np.all(np.isfinite(target)) and math.isfinite(t0) and math.isfinite(t1)):
            raise ValueError("swing start, target and times must be finite")
        if not t1 > t0:
            raise ValueError(f"touch-down time {t1} must be after lift-off {t0}")
        if not (apex >= 0 and 0 < apex_fraction < 1):
            raise ValueError("apex must be >= 0 and apex_fraction in (0, 1)")
        self.t0, self.t1 = float(t0), float(t1)
        self.apex_height = max(start[2], target[2]) + apex
        self.apex_time = t0 + apex_fraction * (t1 - t0)
        self.target = target.copy()
        zero = (0.0, 0.0)
        self._axes = [_Chain([t0, t1], [_quintic(t0, t1, (start[i], *zero), (target[i], *zero))]) for i in (0, 1, 3)]
        self._z = _Chain(
            [t0, self.apex_time, t1],
            [_quintic(t0, self.apex_time, (start[2], *zero), (self.apex_height, *zero)), _quintic(self.apex_time, t1, (self.apex_height, *zero), (target[2], *zero))],
        )
        self._table = np.zeros((4, SWING_COLUMNS))  # the chains for the compiled state (kernels.swing_state)
        self._state = np.empty((4, 3))
        self._tabulate()

    def _tabulate(self) -> None:
        """Write the four chains (x, y, z, yaw) into the kernel's table (after every change of them)."""
        table = self._table
        x, y, yaw = self._axes
        for row, chain in enumerate((x, y, self._z, yaw)):
            pieces = chain._floats
            table[row, 0] = len(pieces)
            table[row, 1: 1 + len(chain.knots)] = chain.knots
            for index, piece in enumerate(pieces):
                table[row, 4 + 6 * index: 10 + 6 * index] = piece

    def evaluate(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, z, yaw) position, velocity and acceleration at ``t`` (held at rest outside the swing)."""
        x, y, z, yaw = self.state(t)
        return np.array([x[0], y[0], z[0], yaw[0]]), np.array([x[1], y[1], z[1], yaw[1]]), np.array([x[2], y[2], z[2], yaw[2]])

    def state(self, t: float) -> tuple[tuple[float, float, float], ...]:
        """:meth:`evaluate`'s numbers as floats, per coordinate (x, y, z, yaw): (position, velocity,
        acceleration); the chains' values (:class:`_Chain`), computed by the compiled
        :func:`~giwbc.locomotion.kernels.swing_state` (every tick of a swing)."""
        x, y, z, yaw = self.state_rows(t)
        return tuple(x), tuple(y), tuple(z), tuple(yaw)

    def state_rows(self, t: float) -> list[list[float]]:
        """:meth:`state` as four lists (x, y, z, yaw) of (position, velocity, acceleration)."""
        out = self._state
        swing_state(float(t), self._table, out)
        return out.tolist()

    def retarget(self, t: float, target: np.ndarray | None = None, touchdown: float | None = None, min_remaining: float = 0.02) -> None:
        """From time ``t`` on, go to ``target`` (default: the current one) landing at
        ``touchdown`` (default: the current time), continuing from the state at ``t``."""
        touchdown = self.t1 if touchdown is None else float(touchdown)
        target = self.target if target is None else np.asarray(target, dtype=float).reshape(4)
        if not (np.isfinite(target).all() and math.isfinite(touchdown)):  # (the method: np.all without its dispatch)
            raise ValueError("swing re-target must be finite")
        if t >= self.t1:
            return  # already landed (or past it): nothing left to re-plan
        touchdown = max(touchdown, t + min_remaining)
        now = self.state(t)  # (position, velocity, acceleration) per coordinate
        self.target = target.copy()
        end = (0.0, 0.0)
        self._axes = [
            _Chain([t, touchdown], [_quintic(t, touchdown, now[i], (target[i], *end))]) for i in (0, 1, 3)
        ]
        # The apex keeps its share of the swing; once past it, straight down to the target.
        apex_time = self.t0 + (self.apex_time - self.t0) / (self.t1 - self.t0) * (touchdown - self.t0)
        if apex_time - t > min_remaining and t < self.apex_time:
            self._z = _Chain(
                [t, apex_time, touchdown],
                [
                    _quintic(t, apex_time, now[2], (self.apex_height, *end)),
                    _quintic(apex_time, touchdown, (self.apex_height, *end), (target[2], *end)),
                ],
            )
        else:
            self._z = _Chain([t, touchdown], [_quintic(t, touchdown, now[2], (target[2], *end))])
            apex_time = t
        self.apex_time, self.t1 = apex_time, touchdown
        self._table[:] = 0.0
        self._tabulate()
