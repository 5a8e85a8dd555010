"""Online step adjustment: where and when the next foot lands, from the measured DCM.

With the CoP held at ``p`` (the stance sole) for the rest ``T`` of the step, the DCM ends the
step at ``ξ_end = p + (ξ − p) σ``, ``σ = e^{ωT}`` — *linear* in σ. A small QP over the next
footstep ``u`` (x, y) and ``σ`` (Khadiv et al. 2016; Griffin et al. 2017; the ami-iit DCM step
adapter; PlaCo's ``update_supports`` with the measured DCM)::

    min  w_u ‖u − u_nom‖² + w_σ (σ − σ_nom)² + w_b ‖ξ_end(σ) − u − b_nom‖²
    s.t. u inside the kinematic box of the stance foot, σ ∈ [e^{ωT_min}, e^{ωT_max}]

``b_nom`` is the plan's DCM offset at touch-down (``ξ_end − u`` of the nominal plan): with a large
``w_b`` the foot lands where the DCM will be, shifted by that offset. Three variables, box
constraints only, in the stance sole's frame so that the box is axis-aligned. The footstep's
Hessian block is diagonal, so for a fixed σ the optimal ``u`` is the unconstrained one clipped
into the box, affine in σ between the σ where a coordinate meets a bound: the cost is a convex
piecewise quadratic in σ, minimised exactly piece by piece in plain float arithmetic (tens of
µs, deterministic; :func:`solve_box_qp`, the generic enumeration, checks it in the tests).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from giwbc.locomotion.footsteps import Footstep
from giwbc.locomotion.kernels import FUSED_ROWS, FUSED_ROWS_T, STEP_OUTPUTS, step_adapt
from giwbc.locomotion.planar import distance2, rotate, rotate_back


@dataclass(frozen=True)
class StepAdapterWeights:
    position: float = 1.0  # w_u, 1/m²
    timing: float = 0.5  # w_σ
    offset: float = 100.0  # w_b, 1/m²

    def __post_init__(self) -> None:
        for value in (self.position, self.timing, self.offset):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"step adapter weights must be finite and > 0, got {self}")


class StepAdjustment:
    """The adapted next footstep (world x, y), the remaining step time and the predicted DCM.

    ``dcm_at_touchdown`` and ``offset`` (``ξ_end − u``, world) are rotated into the world when
    asked for: the walker's every-tick adaptation reads the footstep and the time only."""

    __slots__ = ("position", "remaining_time", "_frame", "_stance_values")

    def __init__(self, position: np.ndarray, remaining_time: float, frame: StepFrame, stance_values: tuple[float, float, float, float]) -> None:
        self.position, self.remaining_time = position, remaining_time
        self._frame, self._stance_values = frame, stance_values  # (ξ_end x, y, u x, y) in the stance frame

    @property
    def dcm_at_touchdown(self) -> np.ndarray:
        frame = self._frame
        ex, ey, _, _ = self._stance_values
        x, y = rotate(frame.c, frame.s, ex, ey)
        return np.array([frame.ox + x, frame.oy + y])

    @property
    def offset(self) -> np.ndarray:
        frame = self._frame
        ex, ey, ux, uy = self._stance_values
        return np.array(rotate(frame.c, frame.s, ex - ux, ey - uy))

    def landing_moved(self, x: float, y: float) -> StepAdjustment:
        """The same touch-down time and predicted DCM with the landing at ``(x, y)`` in the stance sole's frame."""
        frame = self._frame
        ex, ey, _, _ = self._stance_values
        wx, wy = rotate(frame.c, frame.s, x, y)
        return StepAdjustment(np.array([frame.ox + wx, frame.oy + wy]), self.remaining_time, frame, (ex, ey, x, y))


def solve_box_qp(hessian: np.ndarray, gradient: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``argmin ½ zᵀHz + gᵀz`` s.t. ``lower ≤ z ≤ upper`` for a small positive-definite ``H``:
    every active set (each variable free, at its lower or at its upper bound) is tried; the
    feasible stationary point of least cost is the optimum (convexity)."""
    n = len(gradient)
    best, best_cost = None, math.inf
    for pattern in itertools.product((0, -1, 1), repeat=n):
        pattern = np.array(pattern)
        z = np.where(pattern < 0, lower, np.where(pattern > 0, upper, 0.0)).astype(float)
        free = pattern == 0
        if free.any():
            rhs = -(gradient[free] + hessian[np.ix_(free, ~free)] @ z[~free])
            z[free] = np.linalg.solve(hessian[np.ix_(free, free)], rhs)
        if np.any(z < lower - 1e-12) or np.any(z > upper + 1e-12):
            continue
        cost = 0.5 * z @ hessian @ z + gradient @ z
        if cost < best_cost - 1e-15:
            best, best_cost = z, cost
    if best is None:
        raise ValueError("the step adapter's box is empty (lower bound above upper bound)")
    return best


def step_qp_matrices(w_u: float, w_s: float, w_b: float, u_nom: np.ndarray, sigma_nom: float, d: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(H, g)`` of the step QP in ``z = (u_x, u_y, σ)`` (cost ``½ zᵀHz + gᵀz`` + const):
    ``w_u ‖u − u_nom‖² + w_σ (σ − σ_nom)² + w_b ‖d σ + k − u‖²``."""
    A = np.array([[-1.0, 0.0, d[0]], [0.0, -1.0, d[1]]])
    H = 2.0 * w_b * A.T @ A
    H[:2, :2] += 2.0 * w_u * np.eye(2)
    H[2, 2] += 2.0 * w_s
    g = 2.0 * w_b * A.T @ np.asarray(k, dtype=float)
    g[:2] -= 2.0 * w_u * np.asarray(u_nom, dtype=float)
    g[2] -= 2.0 * w_s * sigma_nom
    return H, g


def solve_step_qp(
    w_u: float, w_s: float, w_b: float, u_nom: np.ndarray, sigma_nom: float, d: np.ndarray, k: np.ndarray,
    lower: tuple[float, float, float], upper: tuple[float, float, float],
) -> np.ndarray:
    """Exact minimiser of the step QP (:func:`step_qp_matrices`) over the box, by pieces in σ."""
    s_lo, s_hi = float(lower[2]), float(upper[2])
    if s_lo > s_hi or lower[0] > upper[0] or lower[1] > upper[1]:
        raise ValueError("the step adapter's box is empty (lower bound above upper bound)")
    # (Per coordinate i = 0, 1 written out: solved at every tick of a swing, plain floats.)
    lo0, lo1, hi0, hi1 = lower[0], lower[1], upper[0], upper[1]
    total = w_u + w_b
    un0, un1, d0, d1, k0, k1 = float(u_nom[0]), float(u_nom[1]), float(d[0]), float(d[1]), float(k[0]), float(k[1])
    # Unconstrained u(σ) = a + b σ, per coordinate.
    a0, a1 = (w_u * un0 + w_b * k0) / total, (w_u * un1 + w_b * k1) / total
    b0, b1 = w_b * d0 / total, w_b * d1 / total
    breaks = {s_lo, s_hi}
    for a, b, lo, hi in ((a0, b0, lo0, hi0), (a1, b1, lo1, hi1)):
        if b != 0.0:
            for bound in (lo, hi):
                sigma = (bound - a) / b
                if s_lo < sigma < s_hi:
                    breaks.add(sigma)
    knots = sorted(breaks)
    best, best_cost = None, math.inf
    for left, right in zip(knots, knots[1:] + ([knots[0]] if len(knots) == 1 else [])):
        middle = 0.5 * (left + right)
        # The active pattern on this piece: u = α + β σ per coordinate.
        u = a0 + b0 * middle
        alpha0, beta0 = (lo0, 0.0) if u < lo0 else (hi0, 0.0) if u > hi0 else (a0, b0)
        u = a1 + b1 * middle
        alpha1, beta1 = (lo1, 0.0) if u < lo1 else (hi1, 0.0) if u > hi1 else (a1, b1)
        # f(σ) = w_u ‖α + βσ − u_n‖² + w_σ (σ − σ_n)² + w_b ‖(d − β)σ + (k − α)‖²
        m0, m1 = d0 - beta0, d1 - beta1
        num = w_s * sigma_nom
        num -= w_u * beta0 * (alpha0 - un0) + w_b * m0 * (k0 - alpha0)
        num -= w_u * beta1 * (alpha1 - un1) + w_b * m1 * (k1 - alpha1)
        den = w_s
        den += w_u * beta0 * beta0 + w_b * m0 * m0
        den += w_u * beta1 * beta1 + w_b * m1 * m1
        sigma = min(max(num / den, left), right) if den > 0.0 else left
        z0 = min(max(alpha0 + beta0 * sigma, lo0), hi0)
        z1 = min(max(alpha1 + beta1 * sigma, lo1), hi1)
        cost = w_u * ((z0 - un0) ** 2 + (z1 - un1) ** 2) + w_s * (sigma - sigma_nom) ** 2
        cost += w_b * ((d0 * sigma + k0 - z0) ** 2 + (d1 * sigma + k1 - z1) ** 2)
        if cost < best_cost:
            best, best_cost = (z0, z1, sigma), cost
    return np.array(best)


def step_cost(w_u: float, w_s: float, w_b: float, u_nom: tuple[float, float], sigma_nom: float, d: tuple[float, float], k: tuple[float, float],
              z: tuple[float, float, float]) -> float:
    """The step QP's cost (:func:`step_qp_matrices`) at ``z = (u_x, u_y, σ)``, plain floats."""
    ux, uy, sigma = z
    cost = w_u * ((ux - u_nom[0]) ** 2 + (uy - u_nom[1]) ** 2) + w_s * (sigma - sigma_nom) ** 2
    return cost + w_b * ((d[0] * sigma + k[0] - ux) ** 2 + (d[1] * sigma + k[1] - uy) ** 2)


@dataclass(frozen=True)
class SwingReach:
    """Where the swinging foot can still get to before it lands: within ``slack + speed · T`` m
    (each axis of the stance frame) of where it is now (``x``, ``y``, stance frame), ``T`` the
    remaining swing time. Without it the adapter may ask for a landing the leg cannot reach in
    the time it chose — a push forward while walking asked for 0.7 m in 0.24 s, and the foot came
    down 0.27 m short of it, late."""

    x: float
    y: float
    speed: float  # m/s, mean horizontal speed of the foot over what is left of the swing
    slack: float  # m: already within reach whatever the time (the foot's momentum, the landing's tolerance)
    pieces: int = 12  # the remaining-time range is cut into this many pieces, each with the reach of its shortest time

    def __post_init__(self) -> None:
        if not (math.isfinite(self.x) and math.isfinite(self.y) and self.speed > 0.0 and math.isfinite(self.speed) and 0.0 <= self.slack < math.inf and self.pieces >= 1):
            raise ValueError(f"swing reach needs a finite foot position, speed > 0, slack >= 0 and pieces >= 1, got {self}")

    def cut(self, box: tuple[tuple[float, float], tuple[float, float]], remaining: float) -> tuple[tuple[float, float], tuple[float, float]]:
        """``box`` cut to what the foot reaches in ``remaining`` s (the box's point nearest the reach when they do not meet)."""
        radius = self.slack + self.speed * remaining
        axes = []
        for (lo, hi), at in zip(box, (self.x, self.y)):
            a, b = max(lo, at - radius), min(hi, at + radius)
            if a > b:  # out of reach: the box's bound nearest the foot
                a = b = lo if at < lo else hi
            axes.append((a, b))
        return axes[0], axes[1]


class StepFrame:
    """What one step's adaptations share (a swing's every tick): the stance sole's frame and the
    plan's next foot and DCM offset in it — made once per step, for :meth:`StepAdapter.adapt_in`."""

    __slots__ = ("c", "s", "ox", "oy", "u_nom", "b_nom", "values")

    def __init__(self, stance: Footstep, nominal_step: np.ndarray, nominal_offset: np.ndarray) -> None:
        (nx, ny), (bx, by) = ((float(v[0]), float(v[1])) for v in (nominal_step, nominal_offset))
        self.ox, self.oy = float(stance.position[0]), float(stance.position[1])
        if not all(math.isfinite(v) for v in (nx, ny, bx, by)):  # (the stance foot is finite: a Footstep)
            raise ValueError("step adapter inputs must be finite")
        # Plain floats, the same bits as the 2 × 2 numpy products they replace (giwbc.locomotion.planar):
        # Rᵀ (x − s) into the stance sole's frame, s + R x back to the world.
        self.c, self.s = c, sn = math.cos(stance.yaw), math.sin(stance.yaw)
        self.u_nom = rotate_back(c, sn, nx - self.ox, ny - self.oy)
        self.b_nom = rotate_back(c, sn, bx, by)
        self.values = np.array([c, sn, self.ox, self.oy, *self.u_nom, *self.b_nom])  # the compiled adaptation's (kernels.STEP_FRAME)


class StepAdapter:
    """The step-adjustment QP of the module docstring for a stance foot and a box of landing spots."""

    def __init__(self, omega: float, weights: StepAdapterWeights | None = None) -> None:
        if not (math.isfinite(omega) and omega > 0):
            raise ValueError(f"omega must be > 0, got {omega}")
        self.omega = float(omega)
        self.weights = weights or StepAdapterWeights()
        self._out = np.empty(STEP_OUTPUTS)  # the compiled adaptation's outputs (kernels.step_adapt), read at once

    def adapt(
        self,
        stance: Footstep,
        cop: np.ndarray,
        dcm: np.ndarray,
        nominal_step: np.ndarray,
        nominal_remaining: float,
        nominal_offset: np.ndarray,
        box: tuple[tuple[float, float], tuple[float, float]],
        remaining_range: tuple[float, float],
    ) -> StepAdjustment:
        """Adapt the next step.

        ``cop``: the CoP held for the rest of the step (world x, y); ``dcm``: the measured DCM;
        ``nominal_step`` (world) and ``nominal_remaining`` (s) the plan's next foot and remaining
        step time; ``nominal_offset`` the plan's ``ξ_end − u`` (world); ``box`` the landing box in
        the stance sole's frame ``((x_lo, x_hi), (y_lo, y_hi))``; ``remaining_range`` the allowed
        remaining time ``(T_min, T_max)``, s.
        """
        return self.adapt_in(StepFrame(stance, nominal_step, nominal_offset), cop, dcm, nominal_remaining, box, remaining_range)

    def adapt_in(
        self,
        frame: StepFrame,
        cop: np.ndarray,
        dcm: np.ndarray,
        nominal_remaining: float,
        box: tuple[tuple[float, float], tuple[float, float]],
        remaining_range: tuple[float, float],
        reach: SwingReach | None = None,
    ) -> StepAdjustment:
        """:meth:`adapt` with its per-step part made already (:class:`StepFrame`): the same numbers.
        With ``reach`` the landing also stays where the swinging foot reaches in the remaining time
        chosen (the time range cut into ``reach.pieces``, each piece solved with the reach of its
        shortest time, so that whatever time the piece picks the landing is reached; the cheapest
        piece wins)."""
        cx, cy, xx, xy = float(cop[0]), float(cop[1]), float(dcm[0]), float(dcm[1])
        finite = math.isfinite
        if not (finite(cx) and finite(cy) and finite(xx) and finite(xy) and finite(nominal_remaining)):
            raise ValueError("step adapter inputs must be finite")
        t_lo, t_hi = remaining_range
        if not (0.0 <= t_lo <= t_hi):
            raise ValueError(f"remaining time range must satisfy 0 <= T_min <= T_max, got {remaining_range}")
        w = self.weights
        # (Compiled, kernels.step_adapt: the same operations as solve_step_qp, SwingReach.cut and
        # step_cost over the pieces, and planar's rotations, bit for bit.)
        (x_lo, x_hi), (y_lo, y_hi) = box
        inputs = np.array((cx, cy, xx, xy, self.omega, t_lo, t_hi, nominal_remaining, w.position, w.timing, w.offset, x_lo, x_hi, y_lo, y_hi,
                           *((0.0, 0.0, 0.0, 0.0, 0.0) if reach is None else (reach.pieces, reach.x, reach.y, reach.speed, reach.slack))), dtype=float)
        out = self._out
        if not step_adapt(frame.values, inputs, FUSED_ROWS, FUSED_ROWS_T, out):
            raise ValueError("the step adapter's box is empty (lower bound above upper bound)")
        wx, wy, remaining, ex, ey, ux, uy = out.tolist()
        return StepAdjustment(np.array([wx, wy]), remaining, frame, (ex, ey, ux, uy))


class DcmErrorShaper:
    """What the step adapter sees of the DCM when the DCM is *estimated* (deployment): the step's
    nominal reference ``ξ_nom(t)`` plus the error ``e = ξ − ξ_nom`` low-passed over
    ``time_constant`` s and shrunk by ``deadband`` m (``e (1 − deadband/‖e‖)⁺``). An error inside
    the deadband gives the adapter the nominal DCM, hence the nominal step and timing; a push still
    moves the landing by all of the error beyond it. Both zero: the measured DCM unchanged.

    With a finite ``full_error`` (m, > ``deadband``) the deadband fades out: an error of that size
    or more passes whole, one between the two is scaled linearly from nothing to all of it — a push
    then moves the landing by all of its error, not by the error less the deadband.

    With a ``fade_delay`` (s, > 0) the fading's extra over the plain deadband comes in linearly over
    that long an error beyond the deadband: a push's error lasts, an estimate's brief swing-end
    excursion does not, and it gets the plain deadband only (an error of ``full_error`` or more still
    passes whole at once)."""

    def __init__(self, deadband: float = 0.0, time_constant: float = 0.0, full_error: float = math.inf, fade_delay: float = 0.0) -> None:
        if not (math.isfinite(deadband) and deadband >= 0.0 and math.isfinite(time_constant) and time_constant >= 0.0):
            raise ValueError(f"deadband and time_constant must be finite and >= 0, got {deadband}, {time_constant}")
        if not (full_error > deadband):
            raise ValueError(f"full_error must exceed the deadband ({deadband}), got {full_error}")
        if not (math.isfinite(fade_delay) and fade_delay >= 0.0):
            raise ValueError(f"fade_delay must be finite and >= 0, got {fade_delay}")
        self.deadband, self.time_constant, self.full_error = float(deadband), float(time_constant), float(full_error)
        self.fade_delay = float(fade_delay)
        self._last: tuple[float, tuple[float, float]] | None = None  # (time, filtered error)
        self._beyond_since: float | None = None  # when the error last went beyond the deadband

    @property
    def active(self) -> bool:
        return self.deadband > 0.0 or self.time_constant > 0.0

    def reset(self) -> None:
        """Forget the filtered error (a new step, a new nominal reference)."""
        self._last = None
        self._beyond_since = None

    def __call__(self, t: float, measured: np.ndarray, nominal: np.ndarray) -> np.ndarray:
        # (Plain floats, x and y: called at every tick of a swing; the same operations as on the
        # 2-vectors, the norm as np.linalg.norm computes it, giwbc.locomotion.planar.distance2.)
        nx, ny = float(nominal[0]), float(nominal[1])
        ex, ey = float(measured[0]) - nx, float(measured[1]) - ny
        if self.time_constant > 0.0 and self._last is not None:
            last_t, (px, py) = self._last
            dt = max(t - last_t, 0.0)
            gain = dt / (self.time_constant + dt)
            ex, ey = px + gain * (ex - px), py + gain * (ey - py)
        self._last = (float(t), (ex, ey))
        size = distance2((ex, ey), (0.0, 0.0))
        plain = max(1.0 - self.deadband / size, 0.0) if size > 0.0 else 0.0  # the deadband's shrink
        scale = plain
        if size >= self.full_error:
            scale = 1.0
        elif math.isfinite(self.full_error):  # fading: |shaped| = full (size - deadband) / (full - deadband)
            scale = max(size - self.deadband, 0.0) * self.full_error / ((self.full_error - self.deadband) * size) if size > 0.0 else 0.0
            if self.fade_delay > 0.0:  # the extra over the plain deadband, by how long the error has lasted
                if size <= self.deadband:
                    self._beyond_since = None
                elif self._beyond_since is None:
                    self._beyond_since = float(t)
                lasted = 0.0 if self._beyond_since is None else min((float(t) - self._beyond_since) / self.fade_delay, 1.0)
                scale = plain + lasted * (scale - plain)
        return np.array([nx + ex * scale, ny + ey * scale])


def bounded_box(box: tuple[tuple[float, float], tuple[float, float]], centre: np.ndarray, bound: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """``box`` ((x_lo, x_hi), (y_lo, y_hi)) cut to within ``bound`` of ``centre`` (clipped into the
    box first) on each axis: the step adapter moves a planned landing at most ``bound``."""
    if not math.isfinite(bound):
        return box
    axes = []
    for (lo, hi), u in zip(box, centre):
        middle = min(max(float(u), lo), hi)
        axes.append((max(lo, middle - bound), min(hi, middle + bound)))
    return axes[0], axes[1]
