"""Build the PyBullet world of a robot description from the same URDF as the MuJoCo and Pinocchio models.

What the builder changes in the URDF before PyBullet reads it (the MuJoCo builder does the same
through ``MjSpec``): every ``<collision>`` is dropped; each foot gets a collision box whose sole
matches the description's contact rectangle and each whole-body primitive of the description
(``[[collision]]``) becomes a ``<box>``, ``<sphere>`` or ``<capsule>``; self-collision is on, less the
description's excluded (adjacent) pairs, as in MuJoCo; links without
``<inertial>`` get an explicit zero mass (PyBullet would otherwise give each of them 1 kg, where
Pinocchio and MuJoCo give 0); visuals are dropped unless asked for (loading the G1 meshes costs
~0.35 s, the bare model ~2 ms). Inertial overrides let a domain randomizer move a link's centre of
mass, which PyBullet cannot change after loading.

:class:`PybulletClient` is one DIRECT physics server owned by one object: no module-level client.
"""

from __future__ import annotations

import functools
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from giwbc.robot.collision import CollisionShape
from giwbc.robot.description import RobotDescription, RobotDescriptionError
from giwbc.robot.mujoco_model import SOLE_THICKNESS

try:  # PyBullet is optional: only this backend needs it.
    import pybullet
except ImportError:  # pragma: no cover - exercised only without pybullet
    pybullet = None


def require_pybullet() -> Any:
    """The ``pybullet`` module, or an ImportError saying how to install it."""
    if pybullet is None:
        raise ImportError("the PyBullet backend needs pybullet: pip install 'pybullet>=3.2.6,<4'")
    return pybullet


@dataclass(frozen=True)
class LinkInertial:
    """Mass and centre of mass (in the URDF link frame) of one link, replacing the URDF's values.

    The rotational inertia about the centre of mass is scaled by ``mass / nominal mass`` (same
    shape, scaled density), as the MuJoCo and Pinocchio randomizers do.
    """

    mass: float
    com: tuple[float, float, float]


class PybulletClient:
    """One DIRECT PyBullet physics server; ``client.fn(...)`` calls ``pybullet.fn(..., physicsClientId=id)``.

    ``PybulletClient(existing_id)`` wraps a server someone else owns and never disconnects it.
    """

    def __init__(self, client_id: int | None = None) -> None:
        pb = require_pybullet()
        self._owned = client_id is None
        self.id = pb.connect(pb.DIRECT) if client_id is None else int(client_id)
        if self.id < 0:
            raise RuntimeError("PyBullet could not start a DIRECT physics server")

    def __getattr__(self, name: str) -> Any:
        attribute = getattr(require_pybullet(), name)
        if not callable(attribute):
            return attribute
        bound = functools.partial(attribute, physicsClientId=self.id)
        self.__dict__[name] = bound  # cache: later look-ups skip __getattr__
        return bound

    @property
    def connected(self) -> bool:
        return pybullet is not None and bool(pybullet.isConnected(physicsClientId=self.id))

    def close(self) -> None:
        """Disconnect a server this object started (idempotent)."""
        if self._owned and self.connected:
            pybullet.disconnect(physicsClientId=self.id)
        self._owned = False


def pybullet_urdf(
    description: RobotDescription,
    *,
    visuals: bool = False,
    inertials: Mapping[str, LinkInertial] | None = None,
    source: str | None = None,
) -> str:
    """The URDF PyBullet loads: foot boxes and primitive shapes for collision, explicit zero masses, optional overrides.

    ``source``: the description's ``urdf_text()`` when the caller has it (resolving it costs ~30 ms).
    """
    try:
        root = ET.fromstring(description.urdf_text() if source is None else source)
    except ET.ParseError as error:
        raise RobotDescriptionError(f"{description.urdf_path}: malformed URDF: {error}") from error
    links = {link.get("name"): link for link in root.iter("link")}
    unknown = set(inertials or ()) - set(links)
    if unknown:
        raise RobotDescriptionError(f"inertial overrides name unknown links {sorted(unknown)}")
    for name, link in links.items():
        for tag in ("collision",) if visuals else ("collision", "visual"):
            for element in link.findall(tag):
                link.remove(element)
        inertial = link.find("inertial")
        if inertial is None:
            inertial = ET.SubElement(link, "inertial")
            ET.SubElement(inertial, "mass", value="0")
            ET.SubElement(inertial, "inertia", ixx="0", iyy="0", izz="0", ixy="0", ixz="0", iyz="0")
        if inertials and name in inertials:
            _override_inertial(inertial, inertials[name])
    for contact in description.contacts:
        center = np.asarray(contact.center, dtype=float) + [0.0, 0.0, SOLE_THICKNESS]
        collision = ET.SubElement(links[contact.link], "collision", name=f"{contact.name}_sole")
        ET.SubElement(collision, "origin", xyz=" ".join(f"{c:.17g}" for c in center), rpy="0 0 0")
        size = (2 * contact.half_length, 2 * contact.half_width, 2 * SOLE_THICKNESS)
        ET.SubElement(ET.SubElement(collision, "geometry"), "box", size=" ".join(f"{s:.17g}" for s in size))
    for shape in description.collision:
        _add_collision(links[shape.link], shape)
    return ET.tostring(root, encoding="unicode")


def _numbers(values: Sequence[float]) -> str:
    return " ".join(f"{v:.17g}" for v in values)


def _add_collision(link: ET.Element, shape: CollisionShape) -> None:
    """A primitive as a URDF ``<collision>`` (PyBullet's capsule: ``length`` is the cylinder's, along z)."""
    collision = ET.SubElement(link, "collision", name=shape.name)
    ET.SubElement(collision, "origin", xyz=_numbers(shape.position), rpy=_numbers(shape.rpy()))
    geometry = ET.SubElement(collision, "geometry")
    if shape.kind == "box":
        ET.SubElement(geometry, "box", size=_numbers([2 * h for h in shape.size]))
    elif shape.kind == "capsule":
        ET.SubElement(geometry, "capsule", radius=f"{shape.size[0]:.17g}", length=f"{2 * shape.size[1]:.17g}")
    else:
        ET.SubElement(geometry, "sphere", radius=f"{shape.size[0]:.17g}")


def _override_inertial(inertial: ET.Element, override: LinkInertial) -> None:
    mass_element = inertial.find("mass")
    nominal = float(mass_element.get("value", 0.0)) if mass_element is not None else 0.0
    if mass_element is None:
        mass_element = ET.SubElement(inertial, "mass")
    mass_element.set("value", f"{override.mass:.17g}")
    origin = inertial.find("origin")
    if origin is None:
        origin = ET.SubElement(inertial, "origin", rpy="0 0 0")
    origin.set("xyz", " ".join(f"{c:.17g}" for c in override.com))
    inertia = inertial.find("inertia")
    if inertia is not None and nominal > 0:
        ratio = override.mass / nominal
        for key in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz"):
            inertia.set(key, f"{float(inertia.get(key, 0.0)) * ratio:.17g}")


def load_robot(client: PybulletClient, description: RobotDescription, urdf: str, base_position: np.ndarray) -> int:
    """Load URDF text into ``client`` (through a file in a private temporary folder, removed at once)."""
    pb = require_pybullet()
    flags = pb.URDF_USE_INERTIA_FROM_FILE | pb.URDF_MAINTAIN_LINK_ORDER
    if description.self_collision:
        flags |= pb.URDF_USE_SELF_COLLISION
    with tempfile.TemporaryDirectory(prefix="giwbc-pybullet-") as folder:
        path = Path(folder) / f"{description.name}.urdf"
        path.write_text(urdf)
        body = client.loadURDF(
            str(path), basePosition=list(base_position), useFixedBase=not description.floating_base, flags=flags
        )
    if body < 0:
        raise RobotDescriptionError(f"{description.urdf_path}: PyBullet cannot load the URDF")
    if description.self_collision:
        exclude_adjacent_pairs(client, description, body)
    return body


def link_indices(client: PybulletClient, description: RobotDescription, body: int) -> dict[str, int]:
    """``link name -> PyBullet link index`` (the base is -1)."""
    indices = {description.base_link: -1}
    for index in range(client.getNumJoints(body)):
        indices[client.getJointInfo(body, index)[12].decode()] = index
    return indices


def exclude_adjacent_pairs(client: PybulletClient, description: RobotDescription, body: int) -> None:
    """Switch off self-collision between the description's excluded link pairs (adjacent collision bodies)."""
    indices = link_indices(client, description, body)
    for a, b in sorted(description.self_collision_exclusions):
        client.setCollisionFilterPair(body, body, indices[a], indices[b], enableCollision=0)


def add_floor(client: PybulletClient, friction: float) -> int:
    """A static plane at z = 0 (no pybullet_data needed)."""
    pb = require_pybullet()
    shape = client.createCollisionShape(pb.GEOM_PLANE)
    floor = client.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=shape)
    client.changeDynamics(floor, -1, lateralFriction=friction, restitution=0.0, spinningFriction=0.0, rollingFriction=0.0)
    return floor
