"""Residuals: a policy's corrections on top of the model-based walking controller — a part of
:class:`~giwbc.locomotion.walker.WalkingController`, which mixes :class:`Residuals` in (it works on
the controller's state).

A step residual moves where the swinging (or next) foot lands and how long it swings; a reference
residual offsets the DCM, CoM height and pelvis orientation references the walker gives the WBC; a
hip residual changes the gain of the walker's hip strategy (``WalkerConfig.hip_roll_gain``).
All zero (the default) leaves every computation of the walker untouched: bit for bit the walker
alone.
"""

from __future__ import annotations

import math

import numpy as np

from giwbc.locomotion.footsteps import Footstep


def error_gate(size: float, start: float, full: float) -> float:
    """How much of a push-only correction acts at a DCM error of ``size`` m: none up to ``start``,
    all from ``full`` on, linear between (a policy's residual gate, the walker's hip strategy)."""
    return min(max((size - start) / (full - start), 0.0), 1.0)


def check_error_gate(value: object, name: str) -> tuple[float, float]:
    """``value`` as an :func:`error_gate`'s ``(start, full)`` m; ``ValueError`` naming ``name`` unless
    two finite numbers with ``0 <= start < full``."""
    pair = tuple(float(x) for x in value)  # type: ignore[union-attr]
    if not (len(pair) == 2 and all(map(math.isfinite, pair)) and 0.0 <= pair[0] < pair[1]):
        raise ValueError(f"{name} must be (start, full) m of DCM error with 0 <= start < full, got {value}")
    return pair  # type: ignore[return-value]


class Residuals:
    """The walking controller's policy residuals (see the module docstring)."""

    def _clear_residuals(self) -> None:
        """All residuals zero."""
        self._step_offset: np.ndarray | None = None  # stance-sole frame (x forward, y left), m
        self._duration_offset = 0.0  # s, added to the nominal single support
        self._swing_nominal = self.config.gait.single_support
        self._dcm_offset: np.ndarray | None = None  # world x, y, m
        self._height_offset = 0.0  # m
        self._orientation_offset: np.ndarray | None = None  # roll, pitch, yaw, rad
        self._orientation_changed = False
        self._hip_gain_offset = 0.0  # rad per m of lateral DCM error, added to WalkerConfig.hip_roll_gain

    def set_hip_residual(self, gain: float) -> None:
        """Add ``gain`` rad/m to the hip strategy's gain (``WalkerConfig.hip_roll_gain``): the pelvis
        rolls by ``-(hip_roll_gain + gain)`` times the lateral DCM error, every tick, within
        ``hip_roll_max`` and the ``hip_gate`` (the walker's own gate: none inside its start)."""
        if not math.isfinite(gain):
            raise ValueError(f"hip residual must be finite, got {gain}")
        self._hip_gain_offset = float(gain)

    def set_step_residual(self, offset: np.ndarray, duration: float = 0.0) -> None:
        """Shift where the swinging (or next) foot lands by ``offset`` (x, y in the stance sole's
        frame, m) on top of the plan and the step adapter's correction, and change the single
        support by ``duration`` s. The result stays inside the step adapter's landing box and
        ``[min_swing, max_swing]``; applied at once to a foot in flight (re-targeted swing)."""
        offset = np.asarray(offset, dtype=float).reshape(2)
        x, y = offset.tolist()  # (floats: set at every agent step, numpy's per-call overhead was most of the cost)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(duration)):
            raise ValueError(f"step residual must be finite, got {offset}, {duration}")
        self._step_offset = np.array([x, y]) if x != 0.0 or y != 0.0 else None
        self._duration_offset = float(duration)

    def set_reference_residual(self, dcm: np.ndarray | None = None, height: float = 0.0, orientation: np.ndarray | None = None) -> None:
        """Offsets on the references the walker gives the WBC: the DCM reference (world x, y, m;
        in steady state a CoM offset), the CoM height (m) and the pelvis orientation (roll, pitch,
        yaw about the walker's heading, rad)."""
        # (Floats: set at every agent step, numpy's per-call overhead on 2- and 3-vectors was most of the cost.)
        shift = [0.0, 0.0] if dcm is None else np.asarray(dcm, dtype=float).reshape(2).tolist()
        turn = [0.0, 0.0, 0.0] if orientation is None else np.asarray(orientation, dtype=float).reshape(3).tolist()
        if not (all(map(math.isfinite, shift)) and all(map(math.isfinite, turn)) and math.isfinite(height)):
            raise ValueError(f"reference residual must be finite, got {dcm}, {height}, {orientation}")
        self._dcm_offset = np.array(shift) if any(shift) else None
        self._height_offset = float(height)
        previous = self._orientation_offset
        if not any(turn):
            orientation_offset = None
            same = previous is None
        else:
            same = previous is not None and previous.tolist() == turn
            orientation_offset = previous if same else np.array(turn)
        if not same:
            self._orientation_changed = True
        self._orientation_offset = orientation_offset

    def _apply_step_offset(self, stance: Footstep, target: Footstep) -> Footstep:
        """``target`` shifted by the step residual (stance-sole frame), clipped into the landing box."""
        if self._step_offset is None:
            return target
        local = stance.to_local(target.position) + self._step_offset
        (x_lo, x_hi), (y_lo, y_hi) = self._landing_box(target.side)
        local = np.array([min(max(local[0], x_lo), x_hi), min(max(local[1], y_lo), y_hi)])
        return Footstep(target.side, stance.to_world(local), target.yaw)

    def _swing_duration(self, nominal: float) -> float:
        """The single support ``nominal`` s changed by the duration residual, within ``[min_swing, max_swing]``."""
        if self._duration_offset == 0.0:
            return nominal
        return min(max(nominal + self._duration_offset, self.config.min_swing), self.config.max_swing)
