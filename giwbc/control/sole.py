"""A foot's sole as the controller models it: its support polygon, the contact wrench cone of that
polygon, and the reduced supports a rolling foot has (an edge, a corner), with the detector that
switches between them.

**Support polygon.** The convex hull of the sole points of the robot description
(:attr:`giwbc.robot.description.ContactRectangle.sole_points`: the rectangle's corners by default,
or the points / polygon the sole really touches through), shrunk about its centroid by the
controller's margin (``scale``).

**Contact wrench cone of a polygon.** The wrenches ``(f, τ)`` about the contact origin (contact
frame) that point forces at the polygon's vertices, each inside its linearized friction pyramid,
can produce: the cone spanned by the ``4k`` pyramid edges. Its faces come from the convex hull of
the edges cut by the plane ``f_z = 1`` (a 5D polytope, qhull), once at construction: ``W w ≤ 0``.
For a rectangle these are the 16 faces of Caron, Pham and Nakamura's closed form.

**Reduced supports.** A foot that rolls onto an edge (or a corner) can no longer push through the
rest of its sole: its CoP lives on that edge. Each edge of the polygon gets a thin strip
(``edge_width`` inward) and each vertex a small corner triangle (``corner_size``); their cones are
precomputed and padded to one row count, so switching support rewrites a contact's friction rows
in place (no new QP layout).

**Torsion** (optional): ``|τ_z| ≤ torsion · f_z`` on every support, below the yaw moment the
polygon's friction allows (``μ (X + Y) f_z`` for a rectangle): a compliant or creeping floor
turns a stance foot under a yaw moment far inside its sliding friction.

**Roll detection** (:class:`RollDetector`): the foot's rotation since the contact was made and its
angular velocity (contact frame) give the sole's tilt predicted ``lookahead`` s ahead; above
``tilt_on`` the foot is on the edge (or corner) the tilt lowers most, back to the full polygon once
the predicted tilt stayed below ``tilt_off`` for ``release_time``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

FULL = 0  # support mode index of the whole polygon
CORNER_SETBACK = 0.003  # m: a corner support starts this far inside the corner, on its bisector


def hull_2d(points: np.ndarray) -> np.ndarray:
    """(k, 2) counter-clockwise convex hull of (n, 2) points (collinear points dropped)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    hull = ConvexHull(points)
    vertices = points[hull.vertices]  # scipy: counter-clockwise in 2D
    return vertices.copy()


def polygon_wrench_cone(vertices: np.ndarray, mu: float) -> np.ndarray:
    """(m, 6) face matrix ``W`` (``W w ≤ 0``, rows of unit norm) of the contact wrench cone of
    point forces at ``vertices`` ((k, 2), contact frame, sole plane z = 0), each in the friction
    pyramid ``|f_x|, |f_y| ≤ μ f_z``. Exact (the cone is spanned by the 4k pyramid edges)."""
    vertices = np.asarray(vertices, dtype=float).reshape(-1, 2)
    sections = []  # each pyramid edge cut at f_z = 1: (f_x, f_y, τ_x, τ_y, τ_z)
    for px, py in vertices:
        for fx, fy in ((mu, mu), (mu, -mu), (-mu, mu), (-mu, -mu)):
            sections.append([fx, fy, py, -px, px * fy - py * fx])
    hull = ConvexHull(np.array(sections))
    rows = []
    for equation in hull.equations:  # normal · y + offset ≤ 0 inside
        normal, offset = equation[:5], equation[5]
        row = np.array([normal[0], normal[1], offset, normal[2], normal[3], normal[4]])
        rows.append(row / np.linalg.norm(row))
    rows_array = np.array(rows)
    _, unique = np.unique(np.round(rows_array, 9), axis=0, return_index=True)
    return rows_array[np.sort(unique)]


def polygon_centroid(vertices: np.ndarray) -> np.ndarray:
    """Area centroid (2,) of a simple polygon given by its (k, 2) vertices in order."""
    vertices = np.asarray(vertices, dtype=float)
    x, y = vertices[:, 0], vertices[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cross = x * y1 - x1 * y
    area = cross.sum() / 2.0
    return np.array([((x + x1) * cross).sum(), ((y + y1) * cross).sum()]) / (6.0 * area)


def scale_polygon(vertices: np.ndarray, scale: float) -> np.ndarray:
    """The polygon shrunk (``scale`` < 1) about its area centroid."""
    vertices = np.asarray(vertices, dtype=float)
    centroid = polygon_centroid(vertices)
    return centroid + scale * (vertices - centroid)


@dataclass(frozen=True)
class SupportMode:
    """One support of a sole: ``kind`` full | edge | corner, the polygon vertices it stands on
    (indices into the sole polygon) and the polygon the CoP must stay in (contact frame)."""

    kind: str
    vertices: tuple[int, ...]
    polygon: np.ndarray


class SoleSupport:
    """A sole polygon, its reduced supports and their wrench cones, padded to one row count
    (see the module docstring). ``full_rows`` overrides the full polygon's cone (a rectangle's
    closed form, so a rectangular foot keeps its exact rows)."""

    def __init__(
        self,
        vertices: np.ndarray,
        mu: float,
        *,
        full_rows: np.ndarray | None = None,
        edge_width: float = 0.01,
        corner_size: float = 0.015,
        torsion: float | None = None,
    ) -> None:
        if torsion is not None and not (math.isfinite(torsion) and torsion > 0.0):
            raise ValueError(f"torsion must be None or a finite lever arm > 0 m, got {torsion!r}")
        polygon = hull_2d(vertices)
        if len(polygon) < 3:
            raise ValueError("a sole polygon needs at least 3 vertices not on one line")
        self.polygon = polygon
        self.mu = float(mu)
        k = len(polygon)
        modes = [SupportMode("full", tuple(range(k)), polygon)]
        cones = [polygon_wrench_cone(polygon, mu) if full_rows is None else np.asarray(full_rows, dtype=float)]
        for i in range(k):  # a strip along each edge, inside the polygon
            a, b = polygon[i], polygon[(i + 1) % k]
            length = float(np.linalg.norm(b - a))
            along = (b - a) / length
            inward = np.array([-along[1], along[0]])  # CCW: the interior is on the left
            width = min(edge_width, 0.5 * _width_along(polygon, inward))
            start = width / math.tan(min(_angle(polygon, i), math.pi / 2))  # clear of the neighbouring edges
            stop = length - width / math.tan(min(_angle(polygon, (i + 1) % k), math.pi / 2))
            if stop - start < 0.2 * length:
                start, stop = 0.4 * length, 0.6 * length
            centre = a + along * 0.5 * (start + stop) + inward * 0.5 * width
            rectangle = SoleRectangle(centre, along, 0.5 * (stop - start), 0.5 * width)
            modes.append(SupportMode("edge", (i, (i + 1) % k), rectangle.corners()))
            cones.append(rectangle.cone(mu))
        for i in range(k):  # a small rectangle on each corner's bisector
            v, before, after = polygon[i], polygon[i - 1], polygon[(i + 1) % k]
            bisector = (after - v) / np.linalg.norm(after - v) + (before - v) / np.linalg.norm(before - v)
            bisector /= np.linalg.norm(bisector)
            half_width = min(0.5 * corner_size, CORNER_SETBACK * math.tan(0.5 * _angle(polygon, i)))
            rectangle = SoleRectangle(v + bisector * (CORNER_SETBACK + 0.5 * corner_size), bisector, 0.5 * corner_size, half_width)
            modes.append(SupportMode("corner", (i,), rectangle.corners()))
            cones.append(rectangle.cone(mu))
        if torsion is not None:  # |τ_z| <= torsion · f_z on every support: a floor that grips less in yaw
            yaw_rows = np.array([[0.0, 0.0, -torsion, 0.0, 0.0, 1.0], [0.0, 0.0, -torsion, 0.0, 0.0, -1.0]]) / math.hypot(torsion, 1.0)
            cones = [np.vstack([cone, yaw_rows]) for cone in cones]
        self.torsion = torsion
        self.modes = modes
        self.counts = [len(cone) for cone in cones]
        self.n_rows = max(self.counts)
        self.matrices = np.zeros((len(modes), self.n_rows, 6))
        for i, cone in enumerate(cones):
            self.matrices[i, : len(cone)] = cone
            self.matrices[i, len(cone) :, 2] = 1.0  # padding: an unbounded copy of the normal-force row
        self.pattern = (self.matrices != 0).any(axis=0)

    def set_torsion(self, torsion: float) -> None:
        """Rewrite every support's two yaw rows for ``|τ_z| ≤ torsion · f_z`` (same rows, same
        count: a walker tightens the bound while it recovers from a push). Only a sole built with a
        torsion has the rows."""
        if self.torsion is None:
            raise ValueError("this sole was built without torsion rows: give it a torsion to change later")
        if not (math.isfinite(torsion) and torsion > 0.0):
            raise ValueError(f"torsion must be a finite lever arm > 0 m, got {torsion!r}")
        scale = math.hypot(torsion, 1.0)
        for matrix, count in zip(self.matrices, self.counts):
            matrix[count - 2 : count] = np.array([[0.0, 0.0, -torsion, 0.0, 0.0, 1.0], [0.0, 0.0, -torsion, 0.0, 0.0, -1.0]]) / scale
        self.torsion = float(torsion)

    def mode_for_tilt(self, tilt: np.ndarray, edge_angle: float = math.radians(30.0)) -> int:
        """The support a sole tilted by ``tilt`` stands on: ``tilt`` (2,) is the height gradient of
        the sole plane (heights ``h = tilt · p`` of the sole points ``p``, contact frame). The
        lowest vertex, with its lower neighbour when the tilt's axis lies within ``edge_angle`` of
        their edge (the foot rolls about that edge), else the corner alone."""
        polygon, k = self.polygon, len(self.polygon)
        heights = polygon @ tilt
        low = int(np.argmin(heights))
        before, after = (low - 1) % k, (low + 1) % k
        other = before if heights[before] < heights[after] else after
        edge = polygon[other] - polygon[low]
        norm = float(np.linalg.norm(tilt)) * float(np.linalg.norm(edge))
        if norm > 0.0 and abs(float(edge @ tilt)) <= math.sin(edge_angle) * norm:
            first = low if other == after else other  # edges are numbered by their first (CCW) vertex
            return 1 + first
        return 1 + k + low


@dataclass
class RollDetector:
    """Which support a foot stands on, from its rotation since contact and its angular velocity
    (module docstring). Thresholds are angles of the sole plane (rad)."""

    tilt_on: float = math.radians(1.0)
    tilt_off: float = math.radians(0.4)
    lookahead: float = 0.02  # s: tilt predicted this far ahead from the angular velocity
    release_time: float = 0.05  # s below tilt_off before the full sole is trusted again

    def __post_init__(self) -> None:
        if not (0.0 < self.tilt_off < self.tilt_on < math.pi / 2):
            raise ValueError(f"roll detector: need 0 < tilt_off < tilt_on < pi/2, got {self.tilt_off}, {self.tilt_on}")
        if self.lookahead < 0.0 or self.release_time < 0.0:
            raise ValueError("roll detector: lookahead and release_time must be >= 0")

    @staticmethod
    def tilt(relative_rotation: np.ndarray, angular_velocity: np.ndarray | None, lookahead: float) -> np.ndarray:
        """Height gradient (2,) of the sole plane in the contact frame, ``lookahead`` s ahead:
        row 2 of the rotation from the contact frame now to where it was made, advanced by the
        angular velocity (contact frame)."""
        gradient = np.array([relative_rotation[2, 0], relative_rotation[2, 1]])
        if angular_velocity is not None and lookahead > 0.0:
            gradient[0] -= lookahead * float(angular_velocity[1])
            gradient[1] += lookahead * float(angular_velocity[0])
        return gradient


@dataclass(frozen=True)
class SoleRectangle:
    """A rectangle in the sole plane: centre, unit axis, half sizes along and across it."""

    centre: np.ndarray
    axis: np.ndarray
    half_length: float
    half_width: float

    def corners(self) -> np.ndarray:
        across = np.array([-self.axis[1], self.axis[0]])
        return np.array([self.centre + sx * self.half_length * self.axis + sy * self.half_width * across for sx, sy in ((1, 1), (1, -1), (-1, -1), (-1, 1))])

    def cone(self, mu: float) -> np.ndarray:
        """Its contact wrench cone's 16 faces for wrenches about the contact origin (contact frame):
        the closed form about its centre in its own axes, moved (``w' = T w``)."""
        from giwbc.control.contacts import wrench_cone_matrix

        c, s = float(self.axis[0]), float(self.axis[1])
        rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # rectangle axes -> contact frame
        px, py = float(self.centre[0]), float(self.centre[1])
        skew = np.array([[0.0, 0.0, py], [0.0, 0.0, -px], [-py, px, 0.0]])  # [p]x
        transform = np.zeros((6, 6))
        transform[:3, :3] = rotation.T
        transform[3:, 3:] = rotation.T
        transform[3:, :3] = -rotation.T @ skew  # tau about the centre = tau - p x f
        rows = wrench_cone_matrix(self.half_length, self.half_width, mu) @ transform
        return rows / np.linalg.norm(rows, axis=1, keepdims=True)


def _angle(polygon: np.ndarray, i: int) -> float:
    """Interior angle (rad) of the convex polygon at vertex ``i``."""
    v, before, after = polygon[i], polygon[i - 1], polygon[(i + 1) % len(polygon)]
    a, b = before - v, after - v
    return math.acos(min(max(float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0), 1.0))


def _width_along(polygon: np.ndarray, direction: np.ndarray) -> float:
    """Extent of the polygon along ``direction`` (unit)."""
    projection = polygon @ direction
    return float(projection.max() - projection.min())


__all__ = ["FULL", "RollDetector", "SoleRectangle", "SoleSupport", "SupportMode", "hull_2d", "polygon_centroid", "polygon_wrench_cone", "scale_polygon"]
