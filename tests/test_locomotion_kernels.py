"""The walking controller's compiled kernels (issue 37, giwbc/locomotion/kernels.py) against the Python
they replaced, bit for bit, compiled and uncompiled, on random swings, DCM plans and support polygons."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion import kernels
from giwbc.locomotion.dcm import CopSegment, DcmController, DcmReference, walking_cop_plan
from giwbc.locomotion.planar import dot2, fma
from giwbc.locomotion.support import clip_along_ray, convex_hull, signed_distance, sole_corners
from giwbc.locomotion.swing import SwingTrajectory
from giwbc.util.jit import reference

KERNEL_PATHS = [pytest.param(lambda kernel: kernel, id="compiled"), pytest.param(reference, id="python")]


def _bits(values: object) -> bytes:
    return np.asarray(values, dtype=float).tobytes()


def _chain_state(swing: SwingTrajectory, t: float) -> tuple[tuple[float, float, float], ...]:
    """The swing's state from its quintic chains, in Python (the implementation before the kernel)."""
    x, y, yaw = swing._axes
    return x(t), y(t), swing._z(t), yaw(t)


def _random_swing(rng: np.random.Generator) -> SwingTrajectory:
    t0 = rng.uniform(0.0, 5.0)
    start = np.array([*rng.uniform(-1.0, 1.0, 2), rng.uniform(-0.01, 0.05), rng.uniform(-3.0, 3.0)])
    target = start + np.array([*rng.uniform(-0.4, 0.4, 2), rng.uniform(-0.03, 0.03), rng.uniform(-0.5, 0.5)])
    return SwingTrajectory(t0, t0 + rng.uniform(0.2, 0.6), start, target, apex=rng.uniform(0.0, 0.12), apex_fraction=rng.uniform(0.2, 0.8))


@pytest.mark.parametrize("path", KERNEL_PATHS)
def test_swing_state_is_the_quintic_chains_bit_for_bit(path) -> None:
    rng = np.random.default_rng(20370)
    kernel = path(kernels.swing_state)
    out = np.empty((4, 3))
    checked = moving = 0
    for _ in range(60):
        swing = _random_swing(rng)
        for retarget in range(4):
            span = swing.t1 - swing.t0
            times = [swing.t0 - 0.1, swing.t0, swing.apex_time, swing.t1, swing.t1 + 0.05, math.nan, *rng.uniform(swing.t0 - 0.05, swing.t1 + 0.05, 12)]
            for t in times:
                kernel(float(t), swing._table, out)
                expected = _chain_state(swing, t)
                assert _bits(out) == _bits(expected), (t, out, expected)
                assert _bits(swing.state(t)) == _bits(expected)
                checked += 1
                moving += bool(np.any(out[:, 1] != 0.0))
            # re-targeted in flight (one or two z pieces after it), as the step adapter does
            t = swing.t0 + rng.uniform(0.05, 0.9) * span if retarget < 3 else swing.t1 - 0.01
            target = swing.target + np.array([*rng.uniform(-0.05, 0.05, 2), 0.0, rng.uniform(-0.1, 0.1)])
            swing.retarget(t, target, swing.t1 + rng.uniform(-0.05, 0.08))
    assert checked == 60 * 4 * 18
    assert moving > checked // 3  # many samples inside a swing, the feet moving


def _random_plan(rng: np.random.Generator, t0: float) -> DcmReference:
    stance = rng.uniform(-0.5, 0.5, 2)
    landings = [stance + np.array([0.2 * (i + 1), (-1) ** i * 0.2]) + rng.uniform(-0.05, 0.05, 2) for i in range(int(rng.integers(0, 4)))]
    final = None if rng.random() < 0.5 else stance + rng.uniform(-0.1, 0.1, 2)
    current = CopSegment(rng.uniform(0.01, 0.4), stance + rng.uniform(-0.05, 0.05, 2), stance)
    segments = walking_cop_plan(current, landings, rng.uniform(0.25, 0.45), rng.uniform(0.05, 0.2), final)
    return DcmReference(segments, rng.uniform(3.0, 4.5), t0)


@pytest.mark.parametrize("path", KERNEL_PATHS)
def test_dcm_evaluate_is_the_float_implementation_bit_for_bit(path) -> None:
    rng = np.random.default_rng(20371)
    kernel = path(kernels.dcm_evaluate)
    out = np.empty(6)
    for _ in range(200):
        plan = _random_plan(rng, rng.uniform(0.0, 10.0))
        boundaries = [*plan.starts.tolist(), plan.end_time - 1e-12]
        times = [plan.starts[0] - 0.2, *boundaries, math.nan, *rng.uniform(plan.starts[0] - 0.05, plan.end_time, 10)]
        for t in times:
            kernel(float(t), plan._table, plan.omega, out)
            expected = plan._evaluate_floats(t)
            assert _bits(out) == _bits(np.concatenate(expected)), (t, out, expected)
            assert _bits(np.concatenate(plan.evaluate(t))) == _bits(np.concatenate(expected))
        after = plan.evaluate(plan.end_time + 0.1)  # at rest on the terminal CoP (not the kernel's)
        assert _bits(np.concatenate(after)) == _bits(np.concatenate(plan._evaluate_floats(plan.end_time + 0.1)))


def _random_hull(rng: np.random.Generator) -> np.ndarray:
    kind = rng.integers(0, 3)
    left = sole_corners(rng.uniform(-0.1, 0.1, 2), rng.uniform(-0.5, 0.5), 0.085, 0.03)
    if kind == 0:
        return convex_hull(left)
    if kind == 1:
        right = sole_corners(left.mean(axis=0) + rng.uniform(-0.2, 0.2, 2), rng.uniform(-0.5, 0.5), 0.085, 0.03)
        return convex_hull(np.vstack([left, right]))
    return convex_hull(rng.uniform(-0.2, 0.2, (int(rng.integers(3, 9)), 2)))


@pytest.mark.parametrize("path", KERNEL_PATHS)
def test_clip_along_ray_is_the_python_clip_bit_for_bit(path) -> None:
    """Every case: the CoP inside, clipped where the ray leaves the polygon (an edge rate rounded as
    numpy's gemv), the DCM outside (the nearest point), a two-vertex support."""
    rng = np.random.default_rng(20372)
    kernel = path(kernels.clip_cop_along_ray)
    cases = {"inside": 0, "along the ray": 0, "nearest": 0}
    for _ in range(3000):
        hull = _random_hull(rng) if rng.random() < 0.9 else rng.uniform(-0.2, 0.2, (2, 2))
        origin = hull.mean(axis=0) + rng.normal(0.0, 0.05, 2)
        point = origin + rng.normal(0.0, rng.choice([0.01, 0.05, 0.3]), 2)
        out = np.empty(2)
        assert kernel(float(origin[0]), float(origin[1]), float(point[0]), float(point[1]), hull, kernels.FUSED_ROWS, out)
        expected = clip_along_ray(origin, point, hull)
        assert _bits(out) == _bits(expected), (origin, point, hull)
        inside = len(hull) > 2 and signed_distance(origin, hull) <= 0.0
        cases["inside" if _bits(expected) == _bits(point) else "along the ray" if inside else "nearest"] += 1
    assert min(cases.values()) > 300, cases
    assert not kernel(0.5, 0.0, 0.6, 0.1, np.array([[0.0, 0.0]]), kernels.FUSED_ROWS, np.empty(2))  # one point: Python's


@pytest.mark.parametrize("path", KERNEL_PATHS)
def test_edge_rate_rounds_as_numpy_gemv(path) -> None:
    """The clip's edge rate, fused or not, against planar's numpy-probed rounding (dot2) and the
    exact fma, on random values and on rows where the fused and plain roundings differ."""
    rng = np.random.default_rng(20374)
    kernel = path(kernels._edge_rate)
    a = 1.0 + 2.0**-30
    rows = [(a, 1.0, a, -1.0), *(tuple(rng.normal(0.0, 10.0 ** rng.integers(-3, 3), 4)) for _ in range(5000))]
    differ = 0
    for ey, ex, dx, dy in rows:
        assert kernel(ey, ex, dx, dy, True) == fma(ey, dx, -ex * dy)
        assert kernel(ey, ex, dx, dy, False) == ey * dx + -ex * dy
        assert kernel(ey, ex, dx, dy, kernels.FUSED_ROWS) == dot2(ey, -ex, dx, dy)
        differ += fma(ey, dx, -ex * dy) != ey * dx + -ex * dy
    assert differ > 100  # the two roundings were told apart


def test_desired_cop_is_the_python_clip_bit_for_bit() -> None:
    rng = np.random.default_rng(20373)
    controller = DcmController(omega=3.7, gain=4.0)
    for _ in range(2000):
        hull = _random_hull(rng)
        xi = hull.mean(axis=0) + rng.normal(0.0, 0.08, 2)
        xi_ref, rate = xi + rng.normal(0.0, 0.05, 2), rng.normal(0.0, 0.3, 2)
        omega, k = controller.omega, controller.gain / controller.omega
        x, y = float(xi[0]), float(xi[1])
        unclipped = np.array([x - rate[0] / omega + k * (x - xi_ref[0]), y - rate[1] / omega + k * (y - xi_ref[1])])
        expected = clip_along_ray((x, y), unclipped, hull)
        assert _bits(controller.desired_cop(xi, xi_ref, rate, hull)) == _bits(expected)
        assert _bits(controller.desired_cop(xi, xi_ref, rate, np.asfortranarray(hull))) == _bits(expected)  # the Python path
        assert _bits(controller.desired_cop(xi, xi_ref, rate)) == _bits(unclipped)
