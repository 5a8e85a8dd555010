"""Whole-body collision geometry of a robot description: primitive shapes in link frames.

Why primitives: a fallen robot must rest on its body, not sink through the floor, but mesh
collisions double MuJoCo's step cost on the G1; boxes, capsules and spheres cost little and
behave the same in MuJoCo and PyBullet.

``robot.toml`` declares the shapes, one ``[[collision]]`` table each (link frame, metres)::

    [[collision]]
    link = "left_knee_link"                       # a URDF link
    capsule = { from = [0.01, 0, 0], to = [0, 0, -0.25], radius = 0.045 }
    # or: box = { center = [...], half_extents = [...], rpy = [0, 0, 0] }   (rpy optional)
    # or: sphere = { center = [...], radius = ... }
    # or: fit = "capsule" | "box" | "sphere"      (fitted to the link's URDF collision geometry)

A fit is the fallback for links nobody measured: a capsule along the principal axis of the link's
URDF collision points (its visual geometry when it has none), reaching their extent along that
axis, with the 95th percentile of their distance to the axis as radius; a box is their
axis-aligned bounding box in the link frame; a sphere is centred on that box with the 95th
percentile distance as radius.

Self-collision (``[self_collision]``: ``enabled``, default true; ``exclude``, a list of link
pairs) is excluded automatically between *adjacent* collision bodies: links joined by fixed joints
are one rigid body, links without shapes are skipped, and a body is adjacent to the nearest
shape-carrying body above it in the kinematic tree (the pelvis and the thighs through the
shapeless hip links, the torso and the upper arms through the shoulder links). The feet's contact
boxes (``[[contacts]]``) count as shapes of their links.
"""

from __future__ import annotations

import math
import struct
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from giwbc.errors import CollisionError

SHAPE_KINDS = ("box", "capsule", "sphere")
FIT_PERCENTILE = 95.0  # radial percentile of a fitted capsule or sphere: ignores thin protrusions


@dataclass(frozen=True)
class CollisionShape:
    """One primitive in a link frame. ``quaternion`` (w, x, y, z) turns the shape frame into the link frame.

    ``size``: box half extents (3); capsule ``(radius, half_length)`` with its axis along the shape
    frame's z (MuJoCo's and URDF's convention); sphere ``(radius,)``.
    """

    name: str
    link: str
    kind: str
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    size: tuple[float, ...]

    @property
    def rotation(self) -> np.ndarray:
        return quat_to_matrix(np.asarray(self.quaternion, dtype=float))

    @property
    def radius(self) -> float:
        """Capsule/sphere radius; a box's half diagonal."""
        return float(self.size[0]) if self.kind != "box" else float(np.linalg.norm(self.size))

    def endpoints(self) -> np.ndarray:
        """A capsule's segment (2, 3) in the link frame; a sphere or box centre twice."""
        half = self.size[1] if self.kind == "capsule" else 0.0
        axis = self.rotation[:, 2] * half
        center = np.asarray(self.position, dtype=float)
        return np.stack([center - axis, center + axis])

    def rpy(self) -> tuple[float, float, float]:
        """URDF roll-pitch-yaw of the shape frame (``R = Rz(yaw) Ry(pitch) Rx(roll)``)."""
        r = self.rotation
        pitch = math.asin(-max(-1.0, min(1.0, r[2, 0])))
        if abs(r[2, 0]) < 1.0 - 1e-12:
            return math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])
        return math.atan2(-r[1, 2], r[1, 1]), pitch, 0.0

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of link-frame points ``(n, 3)`` to the surface (negative inside)."""
        local = (np.asarray(points, dtype=float) - self.position) @ self.rotation
        if self.kind == "box":
            excess = np.abs(local) - np.asarray(self.size)
            outside = np.linalg.norm(np.maximum(excess, 0.0), axis=1)
            return outside + np.minimum(excess.max(axis=1), 0.0)
        if self.kind == "capsule":
            local = local.copy()
            local[:, 2] -= np.clip(local[:, 2], -self.size[1], self.size[1])
        return np.linalg.norm(local, axis=1) - self.size[0]


# --- rotations -------------------------------------------------------------------------------
def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rpy_to_matrix(rpy: Iterable[float]) -> np.ndarray:
    roll, pitch, yaw = rpy
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def matrix_to_quat(r: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation matrix (Shepperd's method: stable for every rotation)."""
    trace = np.trace(r)
    candidates = [trace, r[0, 0], r[1, 1], r[2, 2]]
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s)
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = ((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s)
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = ((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = ((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s)
    sign = -1.0 if q[0] < 0 else 1.0
    return tuple(float(sign * c) for c in q)  # type: ignore[return-value]


def z_to_axis(axis: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the z axis onto the unit vector ``axis``."""
    z = np.array([0.0, 0.0, 1.0])
    c = float(axis @ z)
    if c < -1.0 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(z, axis)
    skew = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + skew + skew @ skew / (1.0 + c)


# --- shapes from declarations ----------------------------------------------------------------
def capsule(name: str, link: str, start: Iterable[float], end: Iterable[float], radius: float) -> CollisionShape:
    a, b = np.asarray(list(start), dtype=float), np.asarray(list(end), dtype=float)
    length = float(np.linalg.norm(b - a))
    if length < 1e-6:
        raise CollisionError(f"capsule {name!r}: 'from' and 'to' coincide (declare a sphere)")
    if not radius > 0:
        raise CollisionError(f"capsule {name!r}: radius must be > 0")
    rotation = z_to_axis((b - a) / length)
    return CollisionShape(name, link, "capsule", tuple((a + b) / 2), matrix_to_quat(rotation), (float(radius), length / 2))


def box(name: str, link: str, center: Iterable[float], half_extents: Iterable[float], rpy: Iterable[float] = (0, 0, 0)) -> CollisionShape:
    half = tuple(float(h) for h in half_extents)
    if len(half) != 3 or min(half) <= 0:
        raise CollisionError(f"box {name!r}: 'half_extents' needs 3 positive numbers, got {half}")
    return CollisionShape(name, link, "box", tuple(float(c) for c in center), matrix_to_quat(rpy_to_matrix(rpy)), half)


def sphere(name: str, link: str, center: Iterable[float], radius: float) -> CollisionShape:
    if not radius > 0:
        raise CollisionError(f"sphere {name!r}: radius must be > 0")
    return CollisionShape(name, link, "sphere", tuple(float(c) for c in center), (1.0, 0.0, 0.0, 0.0), (float(radius),))


def _vector(table: Mapping[str, Any], key: str, where: str, length: int = 3) -> list[float]:
    value = table.get(key)
    if (
        not isinstance(value, list)
        or len(value) != length
        or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) for v in value)
    ):
        raise CollisionError(f"{where}: {key!r} needs {length} finite numbers, got {value!r}")
    return [float(v) for v in value]


def _scalar(table: Mapping[str, Any], key: str, where: str) -> float:
    value = table.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CollisionError(f"{where}: {key!r} needs a finite number, got {value!r}")
    return float(value)


def parse_shape(table: Mapping[str, Any], where: str, urdf: "UrdfGeometry") -> CollisionShape:
    """One ``[[collision]]`` table: a declared primitive or a fit to the link's URDF geometry."""
    link = table.get("link")
    if not isinstance(link, str):
        raise CollisionError(f"{where}: missing required key 'link' (a link name)")
    if link not in urdf.links:
        raise CollisionError(f"{where}: link {link!r} is not a link of {urdf.path.name}")
    given = [key for key in (*SHAPE_KINDS, "fit") if key in table]
    if len(given) != 1:
        raise CollisionError(f"{where}: give exactly one of 'box', 'capsule', 'sphere' or 'fit', got {given or 'none'}")
    unknown = set(table) - {"link", "name", *given}
    if unknown:
        raise CollisionError(f"{where}: unknown keys {sorted(unknown)}")
    key = given[0]
    name = table.get("name", "")
    if not isinstance(name, str):
        raise CollisionError(f"{where}: 'name' should be a string, got {name!r}")
    if key == "fit":
        kind = table["fit"]
        if kind not in SHAPE_KINDS:
            raise CollisionError(f"{where}: 'fit' should be one of {SHAPE_KINDS}, got {kind!r}")
        return fit_shape(kind, urdf.points(link), name or f"{link}_{kind}", link)
    spec = table[key]
    if not isinstance(spec, dict):
        raise CollisionError(f"{where}: {key!r} should be a table, got {spec!r}")
    name = name or f"{link}_{key}"
    swhere = f"{where} {key}"
    expected = {"capsule": {"from", "to", "radius"}, "box": {"center", "half_extents", "rpy"}, "sphere": {"center", "radius"}}[key]
    if set(spec) - expected:
        raise CollisionError(f"{swhere}: unknown keys {sorted(set(spec) - expected)}; expected {sorted(expected)}")
    if key == "capsule":
        return capsule(name, link, _vector(spec, "from", swhere), _vector(spec, "to", swhere), _scalar(spec, "radius", swhere))
    if key == "box":
        rpy = _vector(spec, "rpy", swhere) if "rpy" in spec else [0.0, 0.0, 0.0]
        return box(name, link, _vector(spec, "center", swhere), _vector(spec, "half_extents", swhere), rpy)
    return sphere(name, link, _vector(spec, "center", swhere), _scalar(spec, "radius", swhere))


# --- fitting -----------------------------------------------------------------------------------
def fit_shape(kind: str, points: np.ndarray, name: str, link: str) -> CollisionShape:
    """A ``kind`` primitive around link-frame points ``(n, 3)`` (see the module docstring)."""
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 4:
        raise CollisionError(f"cannot fit a {kind} to link {link!r}: it has no collision or visual geometry to fit")
    lower, upper = points.min(axis=0), points.max(axis=0)
    if kind == "box":
        return box(name, link, (lower + upper) / 2, np.maximum((upper - lower) / 2, 1e-3))
    if kind == "sphere":
        center = (lower + upper) / 2
        return sphere(name, link, center, float(np.percentile(np.linalg.norm(points - center, axis=1), FIT_PERCENTILE)))
    center = points.mean(axis=0)
    _, vectors = np.linalg.eigh(np.cov((points - center).T))
    axis = vectors[:, -1] * (1.0 if vectors[np.argmax(np.abs(vectors[:, -1])), -1] > 0 else -1.0)
    along = (points - center) @ axis
    radial = np.linalg.norm((points - center) - np.outer(along, axis), axis=1)
    radius = max(float(np.percentile(radial, FIT_PERCENTILE)), 1e-3)
    low, high = along.min() + radius, along.max() - radius
    if high - low < 2e-3:  # shorter than wide: a capsule of (almost) no length
        low = high = (along.min() + along.max()) / 2
        low, high = low - 1e-3, high + 1e-3
    return capsule(name, link, center + low * axis, center + high * axis, radius)


def read_stl(path: Path) -> np.ndarray:
    """Vertices ``(3 n, 3)`` of a binary or ASCII STL file."""
    data = path.read_bytes()
    if len(data) >= 84:
        count = struct.unpack("<I", data[80:84])[0]
        if len(data) == 84 + 50 * count:
            record = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])
            return np.frombuffer(data, dtype=record, count=count, offset=84)["vertices"].reshape(-1, 3).astype(float)
    text = data.decode("ascii", errors="replace")
    vertices = [line.split()[1:4] for line in text.splitlines() if line.strip().startswith("vertex")]
    if not vertices:
        raise CollisionError(f"{path}: not an STL file (or an empty one)")
    return np.array(vertices, dtype=float)


def _sphere_points(radius: float, count: int = 64) -> np.ndarray:
    """Points spread on a sphere (Fibonacci lattice: deterministic, no random draw)."""
    i = np.arange(count) + 0.5
    polar, azimuth = np.arccos(1 - 2 * i / count), math.pi * (1 + 5**0.5) * i
    return radius * np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)


@dataclass(frozen=True)
class UrdfGeometry:
    """The parts of a URDF the collision model needs: links, joints (parent, child, type), link geometry."""

    path: Path
    root: ET.Element

    @classmethod
    def parse(cls, path: Path, text: str) -> "UrdfGeometry":
        return cls(path, ET.fromstring(text))

    @property
    def links(self) -> dict[str, ET.Element]:
        return {link.get("name"): link for link in self.root.iter("link")}

    @property
    def parents(self) -> dict[str, tuple[str, str]]:
        """``child link -> (parent link, joint type)``."""
        return {j.find("child").get("link"): (j.find("parent").get("link"), j.get("type")) for j in self.root.iter("joint")}

    def points(self, link: str) -> np.ndarray:
        """Link-frame points of a link's collision geometry (its visual geometry when it has none)."""
        element = self.links[link]
        parts = element.findall("collision") or element.findall("visual")
        clouds = [self._element_points(part) for part in parts]
        clouds = [c for c in clouds if len(c)]
        return np.concatenate(clouds) if clouds else np.zeros((0, 3))

    def _element_points(self, part: ET.Element) -> np.ndarray:
        geometry = part.find("geometry")
        if geometry is None or len(geometry) == 0:
            return np.zeros((0, 3))
        shape = geometry[0]
        if shape.tag == "mesh":
            points = read_stl(self._mesh_path(shape.get("filename", "")))
            points = points * np.array([float(s) for s in shape.get("scale", "1 1 1").split()])
        elif shape.tag == "box":
            half = np.array([float(s) for s in shape.get("size").split()]) / 2
            points = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T * half
        elif shape.tag == "sphere":
            points = _sphere_points(float(shape.get("radius")))
        elif shape.tag in ("cylinder", "capsule"):
            radius, half = float(shape.get("radius")), float(shape.get("length")) / 2
            angle = np.linspace(0.0, 2 * math.pi, 32, endpoint=False)
            ring = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros_like(angle)], axis=1)
            points = np.concatenate([ring + [0, 0, -half], ring + [0, 0, half]])
        else:
            return np.zeros((0, 3))
        origin = part.find("origin")
        xyz = [float(v) for v in origin.get("xyz", "0 0 0").split()] if origin is not None else [0.0] * 3
        rpy = [float(v) for v in origin.get("rpy", "0 0 0").split()] if origin is not None else [0.0] * 3
        return points @ rpy_to_matrix(rpy).T + xyz

    def _mesh_path(self, filename: str) -> Path:
        if filename.startswith("package://"):
            raise CollisionError(f"{self.path}: cannot resolve mesh {filename!r} to fit a shape; declare the shape instead")
        path = Path(filename.removeprefix("file://"))
        path = path if path.is_absolute() else self.path.parent / path
        if path.suffix.lower() != ".stl":
            raise CollisionError(f"{path}: only STL meshes can be fitted; declare the shape instead")
        if not path.is_file():
            raise CollisionError(f"{path}: mesh file missing (needed to fit a shape)")
        return path


# --- self-collision --------------------------------------------------------------------------
def excluded_pairs(
    parents: Mapping[str, tuple[str, str]], shape_links: Iterable[str], extra: Iterable[tuple[str, str]] = ()
) -> frozenset[tuple[str, str]]:
    """Sorted link pairs among ``shape_links`` that never collide: same rigid body, adjacent bodies, ``extra``.

    ``parents``: ``child -> (parent, joint type)`` of the kinematic tree.
    """
    carriers = set(shape_links)

    def rigid_root(link: str) -> str:
        while link in parents and parents[link][1] == "fixed":
            link = parents[link][0]
        return link

    carrying_roots = {rigid_root(link) for link in carriers}

    def collision_parent(root: str) -> str | None:
        link = root
        while link in parents:
            link = rigid_root(parents[link][0])
            if link in carrying_roots:
                return link
        return None

    ordered = sorted(carriers)
    pairs = set()
    for i, a in enumerate(ordered):
        for b in ordered[i + 1:]:
            ra, rb = rigid_root(a), rigid_root(b)
            if ra == rb or collision_parent(ra) == rb or collision_parent(rb) == ra:
                pairs.add((a, b))
    pairs |= {tuple(sorted(pair)) for pair in extra}  # type: ignore[misc]
    return frozenset(pairs)  # type: ignore[arg-type]
