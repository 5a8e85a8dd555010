"""Support polygons: the convex hull of the soles in contact, point-in-polygon and clipping.

Used to decide when a push needs a step (the capture point left the polygon) and to keep the
CoP a DCM controller asks for realisable (clipped into the polygon). Points are (x, y).
"""

from __future__ import annotations

import math

import numpy as np

from giwbc.locomotion.planar import dot2


def convex_hull(points: np.ndarray) -> np.ndarray:
    """(k, 2) vertices of the convex hull, counter-clockwise (Andrew's monotone chain).

    On Python floats: a hull of two soles' eight corners, computed at every contact switch of a
    walk (a control tick), costs a few microseconds this way and ~30 with numpy's per-call overhead
    (``np.unique`` and indexing per point); the vertices and their order are the same."""
    flat = np.asarray(points, dtype=float).reshape(-1, 2)
    pts = sorted(set(map(tuple, flat.tolist())))  # the distinct points, sorted by x then y
    if len(pts) < 3:
        return np.array(pts, dtype=float).reshape(-1, 2)

    def half(sequence: list[tuple[float, float]]) -> list[tuple[float, float]]:
        chain: list[tuple[float, float]] = []
        for p in sequence:
            while len(chain) >= 2 and _cross(chain[-2], chain[-1], p) <= 0.0:
                chain.pop()
            chain.append(p)
        return chain

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def sole_corners(center: np.ndarray, yaw: float, half_length: float, half_width: float) -> np.ndarray:
    """(4, 2) ground corners of a flat sole centred at ``center`` (x, y) with heading ``yaw``."""
    c, s = np.cos(yaw), np.sin(yaw)
    local = np.array([[half_length, half_width], [half_length, -half_width], [-half_length, -half_width], [-half_length, half_width]])
    return np.asarray(center, dtype=float)[:2] + local @ np.array([[c, s], [-s, c]])


def sole_polygon(center: np.ndarray, yaw: float, polygon: np.ndarray) -> np.ndarray:
    """(k, 2) ground vertices of a sole polygon (k, 2), given in its contact frame, placed at
    ``center`` (x, y) with heading ``yaw``."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.asarray(center, dtype=float)[:2] + np.asarray(polygon, dtype=float) @ np.array([[c, s], [-s, c]])


def _edges(hull: np.ndarray) -> list[tuple[float, float, float, float]]:
    """``(x, y, e_x, e_y)`` per vertex: the vertex and its edge to the next one (CCW)."""
    vertices = hull.tolist()
    following = vertices[1:] + vertices[:1]
    return [(x, y, x1 - x, y1 - y) for (x, y), (x1, y1) in zip(vertices, following)]


def signed_distance(point: np.ndarray, hull: np.ndarray) -> float:
    """Distance from ``point`` to the polygon's boundary: negative inside, positive outside."""
    px, py = float(point[0]), float(point[1])
    depth = -math.inf
    edges = _edges(hull)
    for x, y, ex, ey in edges:
        length = math.sqrt(ey * ey + ex * ex)  # the outward normal (e_y, −e_x), normalised
        d = (px - x) * (ey / length) + (py - y) * (-ex / length) if length > 0.0 else math.nan
        if not d <= 0.0:  # outside (or a degenerate edge, whose normal is NaN): the distance to the boundary
            nearest = hull[0] if len(hull) == 1 else _clip(px, py, edges)
            dx, dy = px - float(nearest[0]), py - float(nearest[1])
            return math.sqrt(dx * dx + dy * dy)
        depth = max(depth, d)
    return depth


def _nearest(px: float, py: float, edges: list[tuple[float, float, float, float]]) -> tuple[float, float]:
    """The nearest point of the polygon's boundary (vertices and edges, :func:`_edges`) to ``(px, py)``."""
    best, bx, by = math.inf, 0.0, 0.0
    for x, y, ex, ey in edges:
        # (min / max written as conditions: the same values, NaN and signed zeros included)
        length2 = ex * ex + ey * ey
        s = ((px - x) * ex + (py - y) * ey) / (1e-18 if 1e-18 > length2 else length2)
        s = 0.0 if 0.0 > s else s
        s = 1.0 if s > 1.0 else s
        cx, cy = x + s * ex, y + s * ey
        distance = (cx - px) * (cx - px) + (cy - py) * (cy - py)
        if distance < best:
            best, bx, by = distance, cx, cy
    return bx, by


def clip_to_polygon(point: np.ndarray, hull: np.ndarray) -> np.ndarray:
    """The point itself when inside the (CCW, convex) polygon, else its nearest boundary point."""
    if len(hull) == 1:
        return hull[0].copy()
    return _clip(float(point[0]), float(point[1]), _edges(hull))


def _clip(px: float, py: float, edges: list[tuple[float, float, float, float]]) -> np.ndarray:
    """:func:`clip_to_polygon` of ``(px, py)`` for a polygon of two or more vertices, given its :func:`_edges`."""
    for x, y, ex, ey in edges:
        if not (px - x) * ey + (py - y) * -ex <= 0.0:
            return np.array(_nearest(px, py, edges))
    return np.array([px, py])


def clip_along_ray(origin: np.ndarray, point: np.ndarray, hull: np.ndarray) -> np.ndarray:
    """``point`` pulled back towards ``origin`` onto the (CCW, convex) polygon, keeping its direction
    from ``origin`` when ``origin`` is inside: the farthest polygon point on the segment
    origin → point. (A DCM controller clipping its CoP this way keeps the direction the DCM is
    pushed in; the nearest-point clip can turn it along an edge.) Falls back to the nearest point
    when ``origin`` is outside.

    Plain floats, a few microseconds for a 4–8-vertex polygon (numpy's per-call overhead was
    most of this function's cost); the same bits as the numpy formulation it replaced
    (:mod:`giwbc.locomotion.planar`)."""
    ox, oy = float(origin[0]), float(origin[1])
    px, py = float(point[0]), float(point[1])
    edges = _edges(hull)
    dx, dy = px - ox, py - oy
    s = 1.0
    for x, y, ex, ey in edges:
        inside = (ox - x) * ey + (oy - y) * -ex  # origin against the outward normal (e_y, −e_x): <= 0 inside
        if inside > 0.0 or len(edges) < 3:
            return hull[0].copy() if len(hull) == 1 else _clip(px, py, edges)
        a, b = ey * dx, ex * dy
        if a - b <= -4e-16 * (abs(a) + abs(b)):
            continue  # an edge the ray moves away from, whatever the last bit of its rate
        if -inside >= (a - b) + 1e-15 * (abs(a) + abs(b)) + 1e-300:
            # The ray meets this edge's line at or beyond ``point`` whatever the last bits of its rate
            # (|rate − (a − b)| ≤ 2.3e-16 (|a| + |b|)): s would stay; no exact rate needed (its fused
            # multiply-add, :func:`dot2`, is most of this function's cost when ``point`` is inside).
            continue
        rate = dot2(ey, -ex, dx, dy)
        if rate > 0.0:
            s = min(s, -inside / rate)
    return np.array([ox + s * dx, oy + s * dy])
