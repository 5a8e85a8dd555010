"""A plant variant: how the simulated robot differs from the controller's model, in physical units.

Every field has a neutral value (the nominal plant giwbc builds from the description); a variant
names only what it changes. Per-joint values are given per joint *group*: a mapping from an
``fnmatch`` pattern over joint names (``"*knee*"``, ``"*ankle_*"``) to a value, the first pattern
that matches a joint wins, joints no pattern matches keep the neutral value, and a pattern that
matches no joint is an error (a typo would otherwise change nothing).

A variant file (TOML, ``robots/<robot>/plants/<name>.toml``)::

    description = "what it models and why"
    [feet]                         # the sole's collision shape (FootShape)
    shape = "capsules"             # box | rounded_box | capsules | corner_spheres | points
    radius = 0.012                 # m
    count = 2                      # capsules: 2 or 3
    points = [[0.08, 0.02], ...]   # points: (x, y) on the sole, m, from the contact centre
    [contact]                      # feet and floor
    solref = [0.02, 1.0]           # time constant s, damping ratio
    solimp = [0.9, 0.95, 0.001, 0.5, 2.0]
    friction = [0.9, 0.005, 0.0001]  # sliding, torsional m, rolling m
    [joints.frictionloss]          # N m (dry friction)
    "*knee*" = 0.6
    [joints.damping]               # N m s/rad (viscous)
    [joints.armature_scale]        # factor on the description's armature
    [joints.effort_scale]          # factor on the effort limit
    [actuators.lag]                # s, first-order torque lag
    [actuators.knee_speed]         # rad/s, full torque up to here
    [actuators.no_load_speed]      # rad/s, no torque left here (motoring)
    [solver]
    iterations = 50                # MuJoCo's constraint solver iterations
    ls_iterations = 20
    [imu]
    rotation = [0.5, -0.5, 0.0]    # mounting error, roll pitch yaw, deg
    offset = [0.003, 0.0, 0.0]     # mounting error, m
"""

from __future__ import annotations

import fnmatch
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from giwbc.errors import PlantMismatchError
from giwbc.util.toml import load_toml

FOOT_SHAPES = ("box", "rounded_box", "capsules", "corner_spheres", "points")
JOINT_PARAMETERS = {  # name: (neutral value, unit, lower bound)
    "frictionloss": (0.0, "N m", 0.0),
    "damping": (0.0, "N m s/rad", 0.0),
    "armature_scale": (1.0, "", 0.0),
    "effort_scale": (1.0, "", 1e-6),
}
ACTUATOR_PARAMETERS = {
    "lag": (0.0, "s", 0.0),
    "knee_speed": (math.inf, "rad/s", 0.0),
    "no_load_speed": (math.inf, "rad/s", 0.0),
}
DEFAULT_SOLREF = (0.02, 1.0)  # MuJoCo's defaults
DEFAULT_SOLIMP = (0.9, 0.95, 0.001, 0.5, 2.0)


@dataclass(frozen=True)
class FootShape:
    """The collision shape of each sole, built on the description's contact rectangle (its lowest
    points on the sole plane, never beyond the rectangle):

    - ``box``: the rectangle as a box (giwbc's nominal foot);
    - ``rounded_box``: a box whose bottom edges are rounded with ``radius`` (a core box and four
      edge capsules): a flat foot that rolls smoothly onto its edge when tilted, as a rubber sole;
    - ``capsules``: ``count`` (2 or 3) capsules of ``radius`` along the foot, spread across its
      width (outer ones tangent to the rectangle's sides);
    - ``corner_spheres``: a sphere of ``radius`` inside each corner;
    - ``points``: a sphere of ``radius`` at each of ``points`` ((x, y) in the sole plane, m, from
      the rectangle's centre).
    """

    shape: str = "box"
    radius: float = 0.0
    count: int = 2
    points: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        if self.shape not in FOOT_SHAPES:
            raise PlantMismatchError(f"foot shape {self.shape!r}: known shapes are {list(FOOT_SHAPES)}")
        if not (math.isfinite(self.radius) and self.radius >= 0):
            raise PlantMismatchError(f"foot shape {self.shape!r}: radius must be a finite length >= 0 m, got {self.radius}")
        if self.shape != "box" and self.radius <= 0:
            raise PlantMismatchError(f"foot shape {self.shape!r} needs a radius > 0 m")
        if self.shape == "capsules" and self.count not in (2, 3):
            raise PlantMismatchError(f"foot shape 'capsules': count must be 2 or 3, got {self.count}")
        if self.shape == "points" and len(self.points) < 3:
            raise PlantMismatchError(f"foot shape 'points' needs at least 3 points (x, y), got {len(self.points)}")

    def sole_points(self, half_length: float, half_width: float) -> np.ndarray:
        """(n, 2) where this shape touches a flat floor (line contacts by their ends), relative to the centre."""
        r, hl, hw = self.radius, half_length, half_width
        if self.shape == "box":
            return np.array([[hl, hw], [hl, -hw], [-hl, hw], [-hl, -hw]])
        if self.shape in ("rounded_box", "corner_spheres"):
            return np.array([[hl - r, hw - r], [hl - r, -(hw - r)], [-(hl - r), hw - r], [-(hl - r), -(hw - r)]])
        if self.shape == "capsules":
            ys = [hw - r, -(hw - r)] if self.count == 2 else [hw - r, 0.0, -(hw - r)]
            return np.array([[x, y] for y in ys for x in (hl - r, -(hl - r))])
        return np.array(self.points, dtype=float).reshape(-1, 2)


@dataclass(frozen=True)
class PlantVariant:
    """The simulated plant's differences from the controller's model (module docstring)."""

    name: str = "nominal"
    description: str = ""
    feet: FootShape = field(default_factory=FootShape)
    solref: tuple[float, float] = DEFAULT_SOLREF
    solimp: tuple[float, float, float, float, float] = DEFAULT_SOLIMP
    friction: tuple[float, float, float] | None = None  # None: the description's floor friction, 0.005, 0.0001
    joints: Mapping[str, Mapping[str, float]] = field(default_factory=dict)  # parameter -> {pattern: value}
    actuators: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    iterations: int | None = None  # None: MuJoCo's default (100)
    ls_iterations: int | None = None  # None: MuJoCo's default (50)
    imu_rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)  # deg, roll pitch yaw
    imu_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m

    def __post_init__(self) -> None:
        where = f"plant variant {self.name!r}"
        for table, known in ((self.joints, JOINT_PARAMETERS), (self.actuators, ACTUATOR_PARAMETERS)):
            for parameter, groups in table.items():
                if parameter not in known:
                    raise PlantMismatchError(f"{where}: unknown parameter {parameter!r}; known: {sorted(known)}")
                lower = known[parameter][2]
                for pattern, value in groups.items():
                    if not (isinstance(value, (int, float)) and not isinstance(value, bool) and value >= lower and not math.isnan(value)):
                        raise PlantMismatchError(f"{where}: {parameter} {pattern!r} must be a number >= {lower}, got {value!r}")
        if len(self.solref) != 2 or not all(math.isfinite(v) for v in self.solref) or self.solref[0] <= 0 or self.solref[1] <= 0:
            raise PlantMismatchError(f"{where}: solref must be (time constant > 0 s, damping ratio > 0), got {self.solref}")
        if len(self.solimp) != 5 or not (0 < self.solimp[0] <= self.solimp[1] < 1) or self.solimp[2] <= 0:
            raise PlantMismatchError(f"{where}: solimp must be (dmin <= dmax in (0, 1), width > 0 m, midpoint, power), got {self.solimp}")
        if self.friction is not None and (len(self.friction) != 3 or min(self.friction) < 0):
            raise PlantMismatchError(f"{where}: friction must be 3 numbers >= 0 (sliding, torsional, rolling), got {self.friction}")
        for name in ("iterations", "ls_iterations"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or value < 1):
                raise PlantMismatchError(f"{where}: {name} must be an integer >= 1, got {value!r}")

    def per_joint(self, parameter: str, joint_names: tuple[str, ...]) -> np.ndarray:
        """One value per joint (description order) of a joint or actuator parameter, from its groups."""
        known = {**JOINT_PARAMETERS, **ACTUATOR_PARAMETERS}
        table = self.joints if parameter in JOINT_PARAMETERS else self.actuators
        groups = table.get(parameter, {})
        values = np.full(len(joint_names), known[parameter][0], dtype=float)
        assigned = np.zeros(len(joint_names), dtype=bool)
        for pattern, value in groups.items():
            hits = np.array([fnmatch.fnmatchcase(name, pattern) for name in joint_names], dtype=bool)
            if not hits.any():
                raise PlantMismatchError(f"plant variant {self.name!r}: {parameter} pattern {pattern!r} matches no joint")
            values[hits & ~assigned] = float(value)
            assigned |= hits
        return values

    def with_name(self, name: str) -> "PlantVariant":
        return replace(self, name=name)


def _tuple(value: Any, size: int, where: str) -> tuple[float, ...]:
    if not (isinstance(value, list) and len(value) == size and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise PlantMismatchError(f"{where}: expected {size} numbers, got {value!r}")
    return tuple(float(v) for v in value)


def variant_from_dict(config: Mapping[str, Any], name: str, where: str | None = None) -> PlantVariant:
    """A variant from the tables of a variant file (module docstring of :mod:`giwbc.plants.variant`)."""
    where = where or f"plant variant {name!r}"
    allowed = {"description", "feet", "contact", "joints", "actuators", "solver", "imu"}
    unknown = sorted(set(config) - allowed)
    if unknown:
        raise PlantMismatchError(f"{where}: unknown table(s) {unknown}; allowed: {sorted(allowed)}")
    feet_table = dict(config.get("feet", {}))
    unknown = sorted(set(feet_table) - {"shape", "radius", "count", "points"})
    if unknown:
        raise PlantMismatchError(f"{where} [feet]: unknown key(s) {unknown}")
    points = tuple(_tuple(p, 2, f"{where} [feet] points") for p in feet_table.get("points", []))
    feet = FootShape(str(feet_table.get("shape", "box")), float(feet_table.get("radius", 0.0)), int(feet_table.get("count", 2)), points)  # type: ignore[arg-type]
    contact = dict(config.get("contact", {}))
    unknown = sorted(set(contact) - {"solref", "solimp", "friction"})
    if unknown:
        raise PlantMismatchError(f"{where} [contact]: unknown key(s) {unknown}")
    solver = dict(config.get("solver", {}))
    unknown = sorted(set(solver) - {"iterations", "ls_iterations"})
    if unknown:
        raise PlantMismatchError(f"{where} [solver]: unknown key(s) {unknown}")
    imu = dict(config.get("imu", {}))
    unknown = sorted(set(imu) - {"rotation", "offset"})
    if unknown:
        raise PlantMismatchError(f"{where} [imu]: unknown key(s) {unknown}")
    return PlantVariant(
        name=name,
        description=str(config.get("description", "")),
        feet=feet,
        solref=_tuple(contact["solref"], 2, f"{where} [contact] solref") if "solref" in contact else DEFAULT_SOLREF,  # type: ignore[arg-type]
        solimp=_tuple(contact["solimp"], 5, f"{where} [contact] solimp") if "solimp" in contact else DEFAULT_SOLIMP,  # type: ignore[arg-type]
        friction=_tuple(contact["friction"], 3, f"{where} [contact] friction") if "friction" in contact else None,  # type: ignore[arg-type]
        joints={k: dict(v) for k, v in dict(config.get("joints", {})).items()},
        actuators={k: dict(v) for k, v in dict(config.get("actuators", {})).items()},
        iterations=solver.get("iterations"),
        ls_iterations=solver.get("ls_iterations"),
        imu_rotation=_tuple(imu["rotation"], 3, f"{where} [imu] rotation") if "rotation" in imu else (0.0, 0.0, 0.0),  # type: ignore[arg-type]
        imu_offset=_tuple(imu["offset"], 3, f"{where} [imu] offset") if "offset" in imu else (0.0, 0.0, 0.0),  # type: ignore[arg-type]
    )


def load_variant(path: str | os.PathLike[str]) -> PlantVariant:
    """A variant file (its name is the file's stem)."""
    path = Path(path)
    return variant_from_dict(load_toml(path, PlantMismatchError), path.stem, str(path))
