"""Support polygons: the convex hull of the soles in contact, point-in-polygon and clipping.

Used to decide when a push needs a step (the capture point left the polygon) and to keep the
CoP a DCM controller asks for realisable (clipped into the polygon). Points are (x, y).
"""

from __future__ import annotations

import numpy as np


def convex_hull(points: np.ndarray) -> np.ndarray:
    """(k, 2) vertices of the convex hull, counter-clockwise (Andrew's monotone chain)."""
    pts = np.unique(np.asarray(points, dtype=float).reshape(-1, 2), axis=0)
    if len(pts) < 3:
        return pts

    def half(sequence: np.ndarray) -> list[np.ndarray]:
        chain: list[np.ndarray] = []
        for p in sequence:
            while len(chain) >= 2 and _cross(chain[-2], chain[-1], p) <= 0.0:
                chain.pop()
            chain.append(p)
        return chain

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def sole_corners(center: np.ndarray, yaw: float, half_length: float, half_width: float) -> np.ndarray:
    """(4, 2) ground corners of a flat sole centred at ``center`` (x, y) with heading ``yaw``."""
    c, s = np.cos(yaw), np.sin(yaw)
    local = np.array([[half_length, half_width], [half_length, -half_width], [-half_length, -half_width], [-half_length, half_width]])
    return np.asarray(center, dtype=float)[:2] + local @ np.array([[c, s], [-s, c]])


def signed_distance(point: np.ndarray, hull: np.ndarray) -> float:
    """Distance from ``point`` to the polygon's boundary: negative inside, positive outside."""
    point = np.asarray(point, dtype=float)[:2]
    edges = np.roll(hull, -1, axis=0) - hull
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)  # outward for a CCW polygon
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    depth = np.einsum("ij,ij->i", point - hull, normals)
    if np.all(depth <= 0.0):
        return float(depth.max())
    return float(np.linalg.norm(point - clip_to_polygon(point, hull)))


def clip_to_polygon(point: np.ndarray, hull: np.ndarray) -> np.ndarray:
    """The point itself when inside the (CCW, convex) polygon, else its nearest boundary point."""
    point = np.asarray(point, dtype=float)[:2]
    if len(hull) == 1:
        return hull[0].copy()
    start = hull
    edges = np.roll(hull, -1, axis=0) - hull
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    if np.all(np.einsum("ij,ij->i", point - start, normals) <= 0.0):
        return point.copy()
    lengths = np.einsum("ij,ij->i", edges, edges)
    s = np.clip(np.einsum("ij,ij->i", point - start, edges) / np.maximum(lengths, 1e-18), 0.0, 1.0)
    candidates = start + s[:, None] * edges
    return candidates[np.argmin(np.einsum("ij,ij->i", candidates - point, candidates - point))]


def clip_along_ray(origin: np.ndarray, point: np.ndarray, hull: np.ndarray) -> np.ndarray:
    """``point`` pulled back towards ``origin`` onto the (CCW, convex) polygon, keeping its direction
    from ``origin`` when ``origin`` is inside: the farthest polygon point on the segment
    origin → point. (A DCM controller clipping its CoP this way keeps the direction the DCM is
    pushed in; the nearest-point clip can turn it along an edge.) Falls back to the nearest point
    when ``origin`` is outside."""
    origin = np.asarray(origin, dtype=float)[:2]
    point = np.asarray(point, dtype=float)[:2]
    edges = np.roll(hull, -1, axis=0) - hull
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)  # outward
    inside_origin = np.einsum("ij,ij->i", origin - hull, normals)  # <= 0 inside
    if len(hull) < 3 or np.any(inside_origin > 0.0):
        return clip_to_polygon(point, hull)
    direction = point - origin
    rates = normals @ direction
    with np.errstate(divide="ignore", invalid="ignore"):
        limits = np.where(rates > 0.0, -inside_origin / rates, np.inf)
    s = min(1.0, float(limits.min()))
    return origin + s * direction
