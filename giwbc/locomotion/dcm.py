"""DCM reference through a footstep plan, and the DCM tracking controller.

**Reference.** The CoP reference is piecewise linear in time: held on the stance sole in single
support, moved linearly from one sole to the next in double support. The DCM reference is found
*backwards* from the end of the plan (where it comes to rest on the final CoP) with the closed
forms of :mod:`giwbc.locomotion.lipm`, then evaluated forwards: ``ξ_ref(t)``, ``ξ̇_ref(t)``,
``p_ref(t)`` are exact LIPM solutions, continuous across segments.

**Controller.** ``ξ̇ = ω (ξ − p)``: asking the DCM error ``e = ξ − ξ_ref`` to decay as ``ė = −k e``
needs the CoP ``p* = ξ − ξ̇_ref / ω + (k / ω) e``; clipped into the support polygon, it sets the
CoM acceleration ``c̈ = ω² (c − p*)`` the WBC's CoM task is asked for. What the clip cannot
absorb is the step adapter's job (:mod:`giwbc.locomotion.step_adapter`).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from giwbc.locomotion.kernels import FUSED_ROWS, clip_cop_along_ray, dcm_evaluate
from giwbc.locomotion.lipm import dcm_at_linear_cop
from giwbc.locomotion.support import clip_along_ray


@dataclass(frozen=True)
class CopSegment:
    """The CoP moving linearly from ``start`` to ``end`` (x, y) over ``duration`` s (equal: held)."""

    duration: float
    start: np.ndarray
    end: np.ndarray


class DcmReference:
    """The DCM reference of a CoP plan starting at ``t0``, at rest on the last CoP at its end."""

    def __init__(self, segments: list[CopSegment], omega: float, t0: float = 0.0) -> None:
        self._set_up(segments, omega, t0, None)

    @classmethod
    def before(cls, segment: CopSegment, rest: DcmReference, t0: float) -> DcmReference:
        """``DcmReference([segment, *rest.segments], rest.omega, t0)`` — the same numbers — with
        ``rest``'s backward pass reused (a double support's plan is made of its own CoP ramp in
        front of the rest of the walk, whose DCM start it needs first)."""
        reference = cls.__new__(cls)
        reference._set_up([segment, *rest.segments], rest.omega, t0, rest)
        return reference

    def _set_up(self, segments: list[CopSegment], omega: float, t0: float, tail: DcmReference | None) -> None:
        """``tail``: a reference of the last segments (its backward pass is theirs here)."""
        if not segments:
            raise ValueError("a DCM reference needs at least one CoP segment")
        if not (math.isfinite(omega) and omega > 0):
            raise ValueError(f"omega must be > 0, got {omega}")
        for segment in segments:
            if not (math.isfinite(segment.duration) and segment.duration > 0):
                raise ValueError(f"CoP segment durations must be > 0, got {segment.duration}")
        self.omega = float(omega)
        self.segments = segments
        durations = np.array([s.duration for s in segments])
        self.starts = t0 + np.concatenate([[0.0], np.cumsum(durations)[:-1]])
        self.end_time = float(t0 + durations.sum())
        self.terminal = np.asarray(segments[-1].end, dtype=float)[:2].copy() if tail is None else tail.terminal.copy()
        head = segments if tail is None else segments[: len(segments) - len(tail.segments)]
        cops = [(tuple(np.asarray(s.start, dtype=float)[:2].tolist()), tuple(np.asarray(s.end, dtype=float)[:2].tolist())) for s in head]
        # Backwards: the DCM at the start of each segment, :func:`~giwbc.locomotion.lipm.dcm_before_linear_cop`
        # on plain floats (the same operations in the same order: a plan is made at every contact switch).
        omega = self.omega
        initial: list[tuple[float, float]] = []
        x, y = self.terminal.tolist() if tail is None else tail._initial[0]
        for s, ((sx, sy), (ex, ey)) in zip(reversed(head), reversed(cops)):
            duration = s.duration
            scale, decay = duration * omega, math.exp(-omega * duration)
            shift_x, shift_y = (ex - sx) / scale, (ey - sy) / scale
            x = float(sx + shift_x + (x - ex - shift_x) * decay)
            y = float(sy + shift_y + (y - ey - shift_y) * decay)
            initial.append((x, y))
        initial.reverse()
        if tail is not None:
            cops += tail._cops
            initial += tail._initial
        self._cops, self._initial = cops, initial
        self.initial = np.array(initial, dtype=float).reshape(len(segments), 2)
        self._starts = self.starts.tolist()
        # Per segment, as floats: (duration, start time, initial DCM, CoP start, CoP end).
        self._floats = [
            (float(seg.duration), start, xi0, *cop) for seg, start, xi0, cop in zip(segments, self._starts, initial, cops)
        ]
        # The same numbers as rows (kernels.dcm_evaluate): duration, start, ξ0, CoP start, CoP end.
        self._table = np.array([(duration, start, *xi0, *cop_start, *cop_end) for duration, start, xi0, cop_start, cop_end in self._floats], dtype=float)

    def segment_index(self, t: float) -> int:
        return max(0, min(bisect.bisect_right(self._starts, t) - 1, len(self.segments) - 1))

    def evaluate(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(ξ_ref, ξ̇_ref, p_ref)`` at time ``t`` (before the start: the start; after the end: rest).

        :func:`~giwbc.locomotion.lipm.dcm_at_linear_cop` element by element (every tick: numpy's
        per-call overhead on 2-vectors was most of its cost), the same operations in the same order,
        compiled (:func:`~giwbc.locomotion.kernels.dcm_evaluate`; the three are views of one new array)."""
        if t >= self.end_time:
            return self.terminal.copy(), np.zeros(2), self.terminal.copy()
        out = np.empty(6)
        dcm_evaluate(float(t), self._table, self.omega, out)
        return out[0:2], out[2:4], out[4:6]

    def _evaluate_floats(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`evaluate` on Python floats (the implementation the kernel replaced; for the tests)."""
        if t >= self.end_time:
            return self.terminal.copy(), np.zeros(2), self.terminal.copy()
        i = self.segment_index(t)
        duration, start_time, (x0, y0), (sx, sy), (ex, ey) = self._floats[i]
        tau = min(max(t - start_time, 0.0), duration)
        omega = self.omega
        growth = math.exp(omega * tau)
        # x, then y, written out
        rate = (ex - sx) / duration
        p = sx + rate * tau
        xi_x = p + rate / omega + (x0 - sx - rate / omega) * growth
        rate_x, cop_x = omega * (xi_x - p), sx + (ex - sx) * (tau / duration)
        rate = (ey - sy) / duration
        p = sy + rate * tau
        xi_y = p + rate / omega + (y0 - sy - rate / omega) * growth
        rate_y, cop_y = omega * (xi_y - p), sy + (ey - sy) * (tau / duration)
        return np.array([xi_x, xi_y]), np.array([rate_x, rate_y]), np.array([cop_x, cop_y])

    def dcm_at_segment_end(self, index: int) -> np.ndarray:
        """The reference DCM at the end of segment ``index`` (the start of the next, or the terminal)."""
        return self.initial[index + 1].copy() if index + 1 < len(self.segments) else self.terminal.copy()


@dataclass
class DcmController:
    """CoP and CoM-acceleration command from the DCM error (see the module docstring)."""

    omega: float
    gain: float = 4.0  # k, s⁻¹: the DCM error's decay rate

    def __post_init__(self) -> None:
        if not (self.omega > 0 and math.isfinite(self.omega)):
            raise ValueError(f"omega must be > 0, got {self.omega}")
        if not (self.gain >= 0 and math.isfinite(self.gain)):
            raise ValueError(f"DCM gain must be finite and >= 0, got {self.gain}")

    def desired_cop(self, xi: np.ndarray, xi_ref: np.ndarray, xi_rate_ref: np.ndarray, support: np.ndarray | None = None) -> np.ndarray:
        """``p* = ξ − ξ̇_ref/ω + (k/ω)(ξ − ξ_ref)``, clipped into ``support`` (CCW hull) when given:
        along the ray from ``ξ`` when ``ξ`` is inside (the DCM keeps being pushed the way the
        controller wants), else to the nearest point."""
        omega, k = self.omega, self.gain / self.omega
        x, y = float(xi[0]), float(xi[1])
        px, py = x - float(xi_rate_ref[0]) / omega + k * (x - float(xi_ref[0])), y - float(xi_rate_ref[1]) / omega + k * (y - float(xi_ref[1]))
        if support is None:
            return np.array([px, py])
        if support.dtype == np.float64 and support.ndim == 2 and support.flags.c_contiguous:
            # clip_along_ray compiled (its same operations and rounding); a one-point support in Python
            out = np.empty(2)
            if clip_cop_along_ray(x, y, px, py, support, FUSED_ROWS, out):
                return out
        return clip_along_ray((x, y), np.array([px, py]), support)

    def com_acceleration(self, com: np.ndarray, cop: np.ndarray) -> np.ndarray:
        """``c̈ = ω² (c − p)`` (horizontal)."""
        w2 = self.omega**2
        return np.array([w2 * (float(com[0]) - float(cop[0])), w2 * (float(com[1]) - float(cop[1]))])


def walking_cop_plan(current: CopSegment, landings: list[np.ndarray], single_support: float, double_support: float, final_cop: np.ndarray | None = None) -> list[CopSegment]:
    """The CoP plan of a walk: ``current`` (the rest of the present phase), then for each landing
    spot a double support moving the CoP onto it and a single support holding it there; with
    ``final_cop``, a last double support moving it there (where the DCM comes to rest)."""
    segments = [current]
    previous = np.asarray(current.end, dtype=float)[:2]
    for landing in landings:
        landing = np.asarray(landing, dtype=float)[:2]
        segments.append(CopSegment(double_support, previous, landing))
        segments.append(CopSegment(single_support, landing, landing))
        previous = landing
    if final_cop is not None:
        segments.append(CopSegment(double_support, previous, np.asarray(final_cop, dtype=float)[:2]))
    return segments
