"""The plain-float 2-D helpers give numpy's bits: the walker's per-tick arithmetic moved off numpy
must not change a single closed-loop torque."""

from __future__ import annotations

import math

import numpy as np

from giwbc.locomotion.footsteps import Footstep, rotation2
from giwbc.locomotion.planar import dot2, fma, rotate, rotate_back
from giwbc.locomotion.support import clip_along_ray, clip_to_polygon, convex_hull, signed_distance, sole_corners


def test_fma_rounds_once() -> None:
    """``fma(a, b, c)`` is ``a·b + c`` rounded once: exact where the separate product loses bits."""
    a = 1.0 + 2.0**-30
    assert fma(a, a, -1.0) == 2.0**-29 + 2.0**-60  # (a² − 1, exact)
    assert a * a - 1.0 != 2.0**-29 + 2.0**-60
    assert fma(3.0, 4.0, 5.0) == 17.0


def test_planar_products_equal_numpy_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    for _ in range(3000):
        yaw = float(rng.uniform(-4.0, 4.0))
        x = rng.normal(size=2) * rng.choice([1e-3, 1.0, 10.0])
        c, s = math.cos(yaw), math.sin(yaw)
        rotation = rotation2(yaw)
        assert rotate(c, s, x[0], x[1]) == tuple(rotation @ x)
        assert rotate_back(c, s, x[0], x[1]) == tuple(rotation.T @ x)
        rows = rng.normal(size=(5, 2))
        assert [dot2(r[0], r[1], x[0], x[1]) for r in rows] == list(rows @ x)
        foot = Footstep("left", rng.normal(size=2), yaw)
        local = rotation.T @ (x - foot.position)
        assert np.array_equal(foot.to_local(x), local) and np.array_equal(foot.to_world(x), foot.position + rotation @ x)


def _numpy_clip_along_ray(origin: np.ndarray, point: np.ndarray, hull: np.ndarray) -> np.ndarray:
    """The numpy formulation the plain-float one replaced (reference)."""
    edges = np.roll(hull, -1, axis=0) - hull
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    inside = np.einsum("ij,ij->i", origin - hull, normals)
    if len(hull) < 3 or np.any(inside > 0.0):
        return clip_to_polygon(point, hull)
    direction = point - origin
    rates = normals @ direction
    with np.errstate(divide="ignore", invalid="ignore"):
        limits = np.where(rates > 0.0, -inside / rates, np.inf)
    return origin + min(1.0, float(limits.min())) * direction


def test_polygon_clips_equal_the_numpy_formulation() -> None:
    rng = np.random.default_rng(1)
    for _ in range(2000):
        soles = [sole_corners(rng.normal(size=2) * 0.1, float(rng.uniform(-1, 1)), 0.1, 0.03) for _ in range(int(rng.integers(1, 3)))]
        hull = convex_hull(np.vstack(soles))
        origin, point = rng.normal(size=2) * 0.1, rng.normal(size=2) * 0.15
        assert np.array_equal(clip_along_ray(origin, point, hull), _numpy_clip_along_ray(origin, point, hull))
        inside = signed_distance(point, hull) <= 0.0
        assert inside == np.array_equal(clip_to_polygon(point, hull), point)


def test_convex_hull_is_the_ccw_strictly_convex_hull_of_its_points() -> None:
    """Duplicates, collinear points and two soles' corners: the hull's vertices are input points,
    counter-clockwise with no collinear vertex, starting at the lowest (x, y); every point lies in it."""
    rng = np.random.default_rng(3)
    for trial in range(300):
        if trial % 3 == 0:
            points = np.vstack([sole_corners(rng.normal(size=2) * 0.2, rng.normal(), 0.1, 0.04) for _ in range(2)])
        else:  # a small integer grid: many duplicates and collinear triples
            points = rng.integers(-2, 3, size=(int(rng.integers(3, 12)), 2)).astype(float)
        hull = convex_hull(points)
        distinct = np.unique(points, axis=0)
        assert {tuple(v) for v in hull.tolist()} <= {tuple(p) for p in points.tolist()}
        if len(distinct) < 3:
            assert np.array_equal(hull, distinct)
            continue
        assert tuple(hull[0]) == tuple(distinct[0])  # Andrew's chain starts at the smallest (x, y)
        edges = np.roll(hull, -1, axis=0) - hull
        turns = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
        if len(hull) >= 3:
            assert (turns > 0).all()  # counter-clockwise, strictly convex
        for p in points:
            cross = edges[:, 0] * (p[1] - hull[:, 1]) - edges[:, 1] * (p[0] - hull[:, 0])
            assert (cross >= -1e-12).all()
