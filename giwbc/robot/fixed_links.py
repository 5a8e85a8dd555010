"""Links joined to their parent by a fixed joint, and the body that carries them in a plant.

A MuJoCo model built elsewhere (a vendor's MJCF, MuJoCo's URDF import with ``fusestatic``) merges
links attached by fixed joints into their parent: the G1's ``imu_in_pelvis``,
``pelvis_contour_link``, ``head_link``... exist in the description (URDF, Pinocchio) but not as
MuJoCo bodies. :func:`carrier` finds, for such a link, the nearest ancestor through fixed joints
that the plant does have, and the link's placement in it, so that what was meant for the link (a
sensor site, a mass change) can be put on the body that carries it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from giwbc.errors import RobotDescriptionError
from giwbc.robot.so3 import rpy_to_matrix


@dataclass(frozen=True)
class Carrier:
    """The plant body carrying a link: the link's frame is ``(position, rotation)`` in the body's frame."""

    body: str
    position: np.ndarray
    rotation: np.ndarray



@lru_cache(maxsize=8)
def fixed_parents(urdf_path: Path) -> dict[str, tuple[str, np.ndarray, np.ndarray]]:
    """``child -> (parent, position, rotation)`` for every URDF joint of type ``fixed``."""
    root = ET.parse(urdf_path).getroot()
    parents: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
    for joint in root.iter("joint"):
        if joint.get("type") != "fixed":
            continue
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            continue
        origin = joint.find("origin")
        xyz = np.array([float(x) for x in origin.get("xyz", "0 0 0").split()]) if origin is not None else np.zeros(3)
        rpy = np.array([float(x) for x in origin.get("rpy", "0 0 0").split()]) if origin is not None else np.zeros(3)
        parents[child.get("link")] = (parent.get("link"), xyz, rpy_to_matrix(rpy))
    return parents


def carrier(urdf_path: Path, bodies: set[str] | frozenset[str], link: str) -> Carrier:
    """The body of ``bodies`` that carries ``link`` (itself when present), through fixed joints.

    Raises RobotDescriptionError (one line, naming the link) when ``link`` is neither a body nor
    joined by fixed joints to one: a moving link the plant does not have.
    """
    position, rotation = np.zeros(3), np.eye(3)
    current = link
    parents = fixed_parents(Path(urdf_path))
    while current not in bodies:
        if current not in parents:
            raise RobotDescriptionError(
                f"the plant has no body {link!r}, and it is not fixed to one it has (merged links follow fixed joints only)"
            )
        parent, xyz, rot = parents[current]
        position, rotation = xyz + rot @ position, rot @ rotation
        current = parent
    return Carrier(current, position, rotation)
