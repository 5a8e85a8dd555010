"""The step adapter's compiled adaptation (issue 37, ``kernels.step_adapt``) against the Python it
replaced (the plain-float QP by pieces, the swing reach's cut, the pieces' costs, planar's rotations):
the same numbers bit for bit, compiled and uncompiled, and the same optimum as the generic box QP."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion.footsteps import Footstep
from giwbc.locomotion.kernels import FUSED_ROWS, FUSED_ROWS_T, STEP_OUTPUTS, step_adapt, step_qp_solve
from giwbc.locomotion.planar import rotate, rotate_back
from giwbc.locomotion.step_adapter import StepAdapter, StepAdapterWeights, StepFrame, SwingReach, solve_box_qp, solve_step_qp, step_cost, step_qp_matrices
from giwbc.util.jit import reference


def _previous_adapt_in(adapter: StepAdapter, frame: StepFrame, cop, dcm, nominal_remaining, box, remaining_range, reach):  # type: ignore[no-untyped-def]
    """``StepAdapter.adapt_in``'s arithmetic before the kernel (e3060cf), verbatim: (landing x, y, remaining time, ξ_end x, y, u x, y)."""
    cx, cy, xx, xy = float(cop[0]), float(cop[1]), float(dcm[0]), float(dcm[1])
    t_lo, t_hi = remaining_range
    w = adapter.weights
    c, sn, ox, oy = frame.c, frame.s, frame.ox, frame.oy
    p = rotate_back(c, sn, cx - ox, cy - oy)
    d = rotate_back(c, sn, xx - cx, xy - cy)
    b_nom = frame.b_nom
    sigma_lo, sigma_hi = math.exp(adapter.omega * t_lo), math.exp(adapter.omega * t_hi)
    sigma_nom = math.exp(adapter.omega * min(max(nominal_remaining, t_lo), t_hi))
    (x_lo, x_hi), (y_lo, y_hi) = box
    k = (p[0] - b_nom[0], p[1] - b_nom[1])
    if reach is None:
        z = solve_step_qp(w.position, w.timing, w.offset, frame.u_nom, sigma_nom, d, k, (x_lo, y_lo, sigma_lo), (x_hi, y_hi, sigma_hi))
    else:
        n = reach.pieces if t_hi > t_lo else 1
        best_cost = math.inf
        for i in range(n):
            a, b = t_lo + (t_hi - t_lo) * i / n, t_lo + (t_hi - t_lo) * (i + 1) / n
            (px_lo, px_hi), (py_lo, py_hi) = reach.cut(box, a)
            piece = solve_step_qp(w.position, w.timing, w.offset, frame.u_nom, sigma_nom, d, k, (px_lo, py_lo, math.exp(adapter.omega * a)),
                                  (px_hi, py_hi, math.exp(adapter.omega * b)))
            cost = step_cost(w.position, w.timing, w.offset, frame.u_nom, sigma_nom, d, k, (float(piece[0]), float(piece[1]), float(piece[2])))
            if cost < best_cost:
                z, best_cost = piece, cost
    ux, uy, sigma = float(z[0]), float(z[1]), float(z[2])
    u_world = rotate(c, sn, ux, uy)
    ex, ey = p[0] + d[0] * sigma, p[1] + d[1] * sigma
    return (ox + u_world[0], oy + u_world[1], math.log(sigma) / adapter.omega, ex, ey, ux, uy)


def _random_case(rng: np.random.Generator):  # type: ignore[no-untyped-def]
    stance = Footstep("left", rng.uniform(-2.0, 2.0, 2), float(rng.uniform(-math.pi, math.pi)))
    frame = StepFrame(stance, stance.position + rng.uniform(-0.4, 0.4, 2), rng.uniform(-0.1, 0.1, 2))
    cop = stance.position + rng.uniform(-0.08, 0.08, 2)
    dcm = cop + rng.normal(0.0, 0.15, 2)
    x = np.sort(rng.uniform(-0.5, 0.5, 2))
    y = np.sort(rng.uniform(-0.6, 0.1, 2))
    box = ((float(x[0]), float(x[1])), (float(y[0]), float(y[1])))
    t_lo = float(rng.uniform(0.0, 0.3))
    remaining_range = (t_lo, t_lo + float(rng.choice([0.0, rng.uniform(0.0, 0.5)])))
    reach = None if rng.random() < 0.4 else SwingReach(float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.4, 0.0)), float(rng.uniform(0.5, 3.0)),
                                                       float(rng.uniform(0.0, 0.1)), int(rng.integers(1, 13)))
    weights = StepAdapterWeights(*rng.uniform(0.1, 200.0, 3))
    return StepAdapter(float(rng.uniform(2.0, 4.5)), weights), frame, cop, dcm, float(rng.uniform(-0.1, 0.6)), box, remaining_range, reach


def test_the_compiled_adaptation_is_the_previous_python_bit_for_bit_on_random_steps() -> None:
    rng = np.random.default_rng(3701)
    reached = 0
    for _ in range(2000):
        adapter, frame, cop, dcm, nominal, box, remaining_range, reach = _random_case(rng)
        expected = _previous_adapt_in(adapter, frame, cop, dcm, nominal, box, remaining_range, reach)
        adjustment = adapter.adapt_in(frame, cop, dcm, nominal, box, remaining_range, reach)
        got = (*adjustment.position.tolist(), adjustment.remaining_time, *adjustment._stance_values)
        assert np.array(got).tobytes() == np.array(expected).tobytes()
        # the landing is inside the box (stance frame) and the time inside its range
        assert box[0][0] - 1e-12 <= got[5] <= box[0][1] + 1e-12 and box[1][0] - 1e-12 <= got[6] <= box[1][1] + 1e-12
        assert remaining_range[0] - 1e-12 <= got[2] <= remaining_range[1] + 1e-12
        reached += reach is not None
    assert reached > 1000  # both paths drawn: with and without the swing's reach


def test_the_kernel_compiled_and_uncompiled_agree_and_an_empty_box_raises() -> None:
    rng = np.random.default_rng(3702)
    plain = reference(step_adapt)
    for _ in range(300):
        adapter, frame, cop, dcm, nominal, box, remaining_range, reach = _random_case(rng)
        w = adapter.weights
        extra = (0.0,) * 5 if reach is None else (reach.pieces, reach.x, reach.y, reach.speed, reach.slack)
        inputs = np.array((*cop, *dcm, adapter.omega, *remaining_range, nominal, w.position, w.timing, w.offset, *box[0], *box[1], *extra), dtype=float)
        fast, slow = np.empty(STEP_OUTPUTS), np.empty(STEP_OUTPUTS)
        assert step_adapt(frame.values, inputs, FUSED_ROWS, FUSED_ROWS_T, fast) and plain(frame.values, inputs, FUSED_ROWS, FUSED_ROWS_T, slow)
        assert fast.tobytes() == slow.tobytes()
    adapter, frame, cop, dcm, nominal, _, remaining_range, _ = _random_case(rng)
    with pytest.raises(ValueError, match="box is empty"):
        adapter.adapt_in(frame, cop, dcm, nominal, ((0.2, 0.1), (-0.3, -0.1)), remaining_range)


def test_the_compiled_qp_is_the_box_qps_optimum() -> None:
    rng = np.random.default_rng(3703)
    out = np.empty(3)
    for _ in range(300):
        w_u, w_s, w_b = rng.uniform(0.1, 200.0, 3)
        u_nom, d, k = rng.uniform(-0.5, 0.5, 2), rng.uniform(-0.5, 0.5, 2), rng.uniform(-0.5, 0.5, 2)
        sigma_nom = float(rng.uniform(1.0, 5.0))
        lower = np.array([*np.sort(rng.uniform(-0.5, 0.5, 2))[:1], -0.6, 1.2])
        upper = np.array([lower[0] + rng.uniform(0.0, 0.5), lower[1] + rng.uniform(0.0, 0.6), lower[2] + rng.uniform(0.0, 3.0)])
        assert step_qp_solve(w_u, w_s, w_b, *u_nom, sigma_nom, *d, *k, *lower, *upper, out)
        assert out.tobytes() == solve_step_qp(w_u, w_s, w_b, u_nom, sigma_nom, d, k, tuple(lower), tuple(upper)).tobytes()
        H, g = step_qp_matrices(w_u, w_s, w_b, u_nom, sigma_nom, d, k)
        exact = solve_box_qp(H, g, lower, upper)
        assert 0.5 * out @ H @ out + g @ out <= 0.5 * exact @ H @ exact + g @ exact + 1e-9
