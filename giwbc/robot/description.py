"""Robot descriptions: one folder per robot, a ``robot.toml`` naming the model source and what a
controller and a deployment need. Both the Pinocchio and the MuJoCo model are built from it.

``load("g1")`` looks the name up in the robot search path (every folder of ``$GIWBC_ROBOT_PATH``,
then the shipped robots: the project's ``robots/`` folder, or the wheel's copy of it);
``load(path)`` takes a robot folder or its ``robot.toml``. A key ``robot.toml`` does not know is
refused (with the closest known key), never ignored; a ``$GIWBC_ROBOT_PATH`` entry that is not a
folder is an error; :func:`scan_robots` loads every robot found, and one that does not load is
reported beside the others, never hides them.
"""

from __future__ import annotations

import difflib
import importlib.metadata
import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.errors import RobotDescriptionError

from giwbc.robot.collision import CollisionError, CollisionShape, UrdfGeometry, excluded_pairs, parse_shape
from giwbc.robot.mujoco_model import build_mujoco_model
from giwbc.robot.pinocchio_model import build_pinocchio_model
from giwbc.util.shipped import shipped_folder
from giwbc.util.toml import TomlPlace, load_toml

if TYPE_CHECKING:
    import mujoco
    import pinocchio

CONFIG_NAME = "robot.toml"
ERD_PREFIX = "erd:"  # a path inside the example-robot-data wheel's share folder
ROBOT_PATH_VARIABLE = "GIWBC_ROBOT_PATH"

# What robot.toml may hold, per table: anything else is a typo or a key of another version, refused.
TOP_LEVEL_KEYS = frozenset({"name", "description", "model", "simulation", "joints", "contacts", "collision", "self_collision"})
MODEL_KEYS = frozenset({"urdf", "floating_base", "base_link", "imu_frame"})
SIMULATION_KEYS = frozenset({"timestep", "integrator", "floor_friction"})
JOINT_KEYS = frozenset({"default", "kp", "kd", "armature", "actuated"})
CONTACT_KEYS = frozenset({"name", "link", "center", "half_length", "half_width", "sole"})


@dataclass(frozen=True)
class JointSpec:
    """One joint of the description: limits come from the URDF, the rest from robot.toml."""

    name: str
    lower: float
    upper: float
    effort: float
    velocity: float
    default: float = 0.0
    kp: float = 0.0
    kd: float = 0.0
    armature: float = 0.0
    actuated: bool = True

    @property
    def unbounded(self) -> bool:
        return self.upper - self.lower > 1e6


@dataclass(frozen=True)
class ContactRectangle:
    """A flat foot: a rectangle in a link frame, sole plane at ``center[2]``.

    The WBC puts a point contact at each corner; MuJoCo gets a collision box with this sole.
    """

    name: str
    link: str
    center: tuple[float, float, float]
    half_length: float
    half_width: float
    sole: tuple[tuple[float, float], ...] = ()  # (x, y) m from ``center``: where the sole touches; () = the 4 corners

    @property
    def sole_points(self) -> np.ndarray:
        """(n, 2) points of the sole plane that touch a flat floor, from ``center`` (m): the
        ``sole`` given in robot.toml (points or a polygon's vertices), else the rectangle's 4
        corners. The support region is their convex hull."""
        if self.sole:
            return np.array(self.sole, dtype=float).reshape(-1, 2)
        x, y = self.half_length, self.half_width
        return np.array([[x, y], [x, -y], [-x, y], [-x, -y]])

    @property
    def corners(self) -> np.ndarray:
        """The 4 corners (4, 3) in the link frame: front-left, front-right, back-left, back-right."""
        signs = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=float)
        corners = np.tile(np.asarray(self.center, dtype=float), (4, 1))
        corners[:, 0] += signs[:, 0] * self.half_length
        corners[:, 1] += signs[:, 1] * self.half_width
        return corners


@dataclass(frozen=True)
class RobotDescription:
    """Everything giwbc knows about one robot, independent of any backend."""

    name: str
    folder: Path
    urdf_path: Path
    floating_base: bool
    base_link: str
    joints: tuple[JointSpec, ...]
    contacts: tuple[ContactRectangle, ...] = ()
    collision: tuple[CollisionShape, ...] = ()  # whole-body primitives; the feet's boxes come from ``contacts``
    self_collision: bool = True
    collision_exclude: tuple[tuple[str, str], ...] = ()  # declared pairs, beyond the automatic adjacent ones
    imu_frame: str | None = None
    timestep: float = 0.002
    integrator: str = "implicitfast"
    floor_friction: float = 1.0
    description: str = ""

    # --- joint arrays, in description order -------------------------------------------------
    @cached_property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @cached_property
    def dofs(self) -> int:
        return len(self.joints)

    def _array(self, field: str) -> np.ndarray:
        return np.array([getattr(j, field) for j in self.joints], dtype=float)

    @property
    def default_positions(self) -> np.ndarray:
        return self._array("default")

    @property
    def kp(self) -> np.ndarray:
        return self._array("kp")

    @property
    def kd(self) -> np.ndarray:
        return self._array("kd")

    @property
    def effort_limits(self) -> np.ndarray:
        """Per-joint effort limit; 0 for a passive joint."""
        return np.where(self._array("actuated") > 0, self._array("effort"), 0.0)

    @property
    def velocity_limits(self) -> np.ndarray:
        return self._array("velocity")

    @property
    def position_limits(self) -> tuple[np.ndarray, np.ndarray]:
        return self._array("lower"), self._array("upper")

    @property
    def actuated(self) -> np.ndarray:
        return self._array("actuated") > 0

    def contact(self, name: str) -> ContactRectangle:
        for contact in self.contacts:
            if contact.name == name:
                return contact
        raise KeyError(f"robot {self.name!r} has no contact {name!r}; it has {[c.name for c in self.contacts]}")

    @cached_property
    def collision_links(self) -> tuple[str, ...]:
        """Links that carry collision geometry (shapes or a foot's contact box), in first-declared order."""
        return tuple(dict.fromkeys([*(c.link for c in self.contacts), *(s.link for s in self.collision)]))

    @cached_property
    def self_collision_exclusions(self) -> frozenset[tuple[str, str]]:
        """Sorted pairs of :attr:`collision_links` that must not collide with each other (see giwbc.robot.collision)."""
        urdf = UrdfGeometry.parse(self.urdf_path, self.urdf_path.read_text())
        return excluded_pairs(urdf.parents, self.collision_links, self.collision_exclude)

    @cached_property
    def default_base_position(self) -> np.ndarray:
        """Base position at the default pose with the lowest sole corner on the floor (z = 0)."""
        if not self.floating_base or not self.contacts:
            return np.zeros(3)
        import pinocchio as pin

        model = self.pinocchio_model
        data = model.createData()
        q = np.concatenate([np.zeros(3), [0.0, 0.0, 0.0, 1.0], self.default_positions])
        pin.framesForwardKinematics(model, data, q)
        lowest = min(
            (data.oMf[model.getFrameId(c.link)].act(corner)[2] for c in self.contacts for corner in c.corners),
        )
        return np.array([0.0, 0.0, -lowest])

    def default_configuration(self) -> np.ndarray:
        """Standing configuration in Pinocchio's convention (free-flyer ``[p, quat_xyzw]`` first)."""
        if not self.floating_base:
            return self.default_positions
        return np.concatenate([self.default_base_position, [0.0, 0.0, 0.0, 1.0], self.default_positions])

    # --- models ----------------------------------------------------------------------------
    def urdf_text(self) -> str:
        """The URDF with ``package://`` URIs resolved to absolute paths."""
        return _resolve_package_uris(self.urdf_path.read_text())

    @cached_property
    def imu_in_base(self) -> "pinocchio.SE3":
        """Placement of the IMU frame in the base frame at the default pose (identity without one)."""
        import pinocchio as pin

        if not self.imu_frame or not self.floating_base:
            return pin.SE3.Identity()
        model = self.pinocchio_model
        data = model.createData()
        pin.framesForwardKinematics(model, data, self.default_configuration())
        return data.oMf[model.getFrameId(self.base_link)].actInv(data.oMf[model.getFrameId(self.imu_frame)])

    @cached_property
    def pinocchio_model(self) -> "pinocchio.Model":
        """The Pinocchio model, parsed from the URDF once per description and shared: read it, make
        your own ``Data`` (``model.createData()``); never modify it (take :meth:`build_pinocchio`)."""
        return build_pinocchio_model(self)

    def build_pinocchio(self) -> "pinocchio.Model":
        """A new Pinocchio model of its own (a copy of :attr:`pinocchio_model`), free to modify."""
        import pinocchio as pin

        return pin.Model(self.pinocchio_model)

    def build_mujoco(self) -> "mujoco.MjModel":
        """A new MuJoCo model (floor, actuators, contact boxes, collision shapes, sensors)."""
        return build_mujoco_model(self)

    @cached_property
    def total_mass(self) -> float:
        root = ET.fromstring(self.urdf_path.read_text())
        return float(sum(float(m.get("value", 0.0)) for m in root.iter("mass")))


# --- loading ---------------------------------------------------------------------------------
def robot_search_path() -> list[Path]:
    """Folders searched for a robot by name: each entry of ``$GIWBC_ROBOT_PATH`` (``os.pathsep``-separated,
    first wins), then the shipped robots. An entry that is not a folder is a RobotDescriptionError:
    whoever set it meant a folder, and a typo there would otherwise only show as an unknown robot."""
    value = os.environ.get(ROBOT_PATH_VARIABLE, "")
    folders = []
    for entry in value.split(os.pathsep):
        if not entry:
            continue
        folder = Path(entry).expanduser()
        if not folder.is_dir():
            reason = "is not a folder" if folder.exists() else "does not exist"
            raise RobotDescriptionError(f"{ROBOT_PATH_VARIABLE} entry {entry!r} {reason} ({ROBOT_PATH_VARIABLE}={value!r}): fix or remove it")
        folders.append(folder)
    shipped = shipped_folder("robots")
    return [*folders, *([shipped] if shipped is not None else [])]


def robot_configs() -> dict[str, Path]:
    """Every robot on the search path: its name (its folder's) and its ``robot.toml``, the first folder's when two share a name."""
    configs: dict[str, Path] = {}
    for folder in robot_search_path():
        for config in sorted(folder.glob(f"*/{CONFIG_NAME}")):
            configs.setdefault(config.parent.name, config)
    return configs


def available_robots() -> list[str]:
    """The names of the robots on the search path (whether each loads or not: see :func:`scan_robots`)."""
    return list(robot_configs())


@dataclass(frozen=True)
class BrokenRobot:
    """A robot on the search path that does not load: its name, its ``robot.toml`` and why."""

    name: str
    config: Path
    error: str


def scan_robots() -> tuple[list[RobotDescription], list[BrokenRobot]]:
    """Load every robot on the search path: the descriptions that load, and those that do not with
    their error (``load`` of such a name raises that error)."""
    loaded, broken = [], []
    for name, config in robot_configs().items():
        try:
            loaded.append(load(config))
        except Exception as error:  # noqa: BLE001 - one broken entry, whatever its defect, must not hide the others
            message = str(error) if isinstance(error, RobotDescriptionError) else f"{config}: {type(error).__name__}: {error}"
            broken.append(BrokenRobot(name, config, " ".join(message.split())))  # one line
    return loaded, broken


def load(robot: str | os.PathLike[str]) -> RobotDescription:
    """Load a robot description by name (``"g1"``) or from a robot folder / ``robot.toml`` path."""
    config_path = _find_config(robot)
    config = load_toml(config_path, RobotDescriptionError)
    return _parse(config, config_path)


def _find_config(robot: str | os.PathLike[str]) -> Path:
    path = Path(robot)
    if path.suffix == ".toml" or path.is_dir() or os.sep in str(robot):
        config = path / CONFIG_NAME if path.suffix != ".toml" else path
        if not config.is_file():
            raise RobotDescriptionError(f"no robot description at {config} (missing file)")
        return config
    for folder in robot_search_path():
        config = folder / str(robot) / CONFIG_NAME
        if config.is_file():
            return config
    raise RobotDescriptionError(f"unknown robot {str(robot)!r}; available robots: {', '.join(available_robots()) or 'none'}")


def _example_robot_data_share() -> Path | None:
    """``.../share/example-robot-data`` inside the installed example-robot-data wheel."""
    try:
        distribution = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        return None
    marker = "share/example-robot-data/package.xml"
    for file in distribution.files or ():
        if str(file).replace(os.sep, "/").endswith(marker):
            return Path(str(distribution.locate_file(file))).parent
    return None


def _resolve_package_uris(urdf: str) -> str:
    """``package://example-robot-data/`` URIs rewritten to the installed wheel's share folder."""
    share = _example_robot_data_share()
    return urdf if share is None else urdf.replace("package://example-robot-data/", f"{share}/")


def _resolve_model_path(source: str, config_path: Path) -> Path:
    if source.startswith(ERD_PREFIX):
        share = _example_robot_data_share()
        if share is None:
            raise RobotDescriptionError(f"{config_path}: model {source!r} needs the example-robot-data package, which is not installed")
        path = share / source[len(ERD_PREFIX):]
    else:
        path = (config_path.parent / source).resolve()
    if not path.is_file():
        raise RobotDescriptionError(f"{config_path}: model file {path} does not exist (missing file)")
    return path


def _sole_points(value: Any, contact: ContactRectangle, where: str) -> tuple[tuple[float, float], ...]:
    """A contact's ``sole``: at least 3 finite (x, y) points (m, from its centre) inside its
    rectangle, not all on one line (the support region is their hull)."""
    if not (isinstance(value, list) and len(value) >= 3 and all(isinstance(p, list) and len(p) == 2 for p in value)):
        raise RobotDescriptionError(f"{where}: 'sole' needs at least 3 points [x, y] (m, from 'center'), got {value!r}")
    if not all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for p in value for c in p):
        raise RobotDescriptionError(f"{where}: 'sole' points must be finite numbers, got {value!r}")
    points = np.array(value, dtype=float)
    outside = (np.abs(points[:, 0]) > contact.half_length + 1e-9) | (np.abs(points[:, 1]) > contact.half_width + 1e-9)
    if outside.any():
        raise RobotDescriptionError(
            f"{where}: 'sole' point {value[int(np.argmax(outside))]} lies outside the sole rectangle (half_length {contact.half_length}, half_width {contact.half_width})"
        )
    edges = points[1:] - points[0]
    if np.abs(edges[:, 0, None] * edges[None, :, 1] - edges[:, 1, None] * edges[None, :, 0]).max() < 1e-8:
        raise RobotDescriptionError(f"{where}: 'sole' points all lie on one line: no support area")
    return tuple((float(x), float(y)) for x, y in points)


def _refuse_unknown(table: dict[str, Any], allowed: frozenset[str], where: str) -> None:
    """A RobotDescriptionError naming the first key of ``table`` not in ``allowed``, and the closest known key."""
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(key, sorted(allowed), n=1)
            hint = f"did you mean {close[0]!r}?" if close else f"known keys: {', '.join(sorted(allowed))}"
            raise RobotDescriptionError(f"{where}: unknown key {key!r} ({hint})")


def _table(config: dict[str, Any], key: str, where: str, allowed: frozenset[str]) -> dict[str, Any]:
    """The optional table ``[key]`` of ``config`` (empty when absent), holding only ``allowed`` keys."""
    table = config.get(key, {})
    if not isinstance(table, dict):
        raise RobotDescriptionError(f"{where}: [{key}] should be a table, got {table!r}")
    _refuse_unknown(table, allowed, f"{where} [{key}]")
    return table


def _flag(table: dict[str, Any], key: str, default: bool, where: str) -> bool:
    """``table[key]`` (``default`` when absent), which must be true or false (a string "false" is no flag)."""
    value = table.get(key, default)
    if not isinstance(value, bool):
        raise RobotDescriptionError(f"{where}: {key!r} should be true or false, got {value!r}")
    return value


def _at(where: str) -> TomlPlace:
    """A place in robot.toml (``where``: the file and the table): its errors are RobotDescriptionError."""
    return TomlPlace(where, RobotDescriptionError)


def _urdf_joint_limits(urdf_path: Path, config_path: Path) -> dict[str, tuple[float, float, float, float]]:
    """``name -> (lower, upper, effort, velocity)`` for every movable URDF joint."""
    try:
        root = ET.parse(urdf_path).getroot()
    except ET.ParseError as error:
        raise RobotDescriptionError(f"{urdf_path}: malformed URDF: {error}") from error
    if root.tag != "robot":
        raise RobotDescriptionError(f"{urdf_path}: not a URDF (root element <{root.tag}>, expected <robot>)")
    limits = {}
    for joint in root.iter("joint"):
        kind = joint.get("type")
        if kind in ("fixed", "floating", None):
            continue
        limit = joint.find("limit")
        if limit is None:
            lower, upper, effort, velocity = -math.inf, math.inf, 0.0, math.inf
        else:
            lower = float(limit.get("lower", -math.inf if kind == "continuous" else 0.0))
            upper = float(limit.get("upper", math.inf if kind == "continuous" else 0.0))
            effort = float(limit.get("effort", 0.0))
            velocity = float(limit.get("velocity", math.inf))
        if kind == "continuous":
            lower, upper = -math.inf, math.inf
        limits[joint.get("name")] = (lower, upper, effort, velocity)
    return limits


def _parse(config: dict[str, Any], config_path: Path) -> RobotDescription:
    where = str(config_path)
    _refuse_unknown(config, TOP_LEVEL_KEYS, where)
    model = _at(where).require(config, "model", dict)
    _refuse_unknown(model, MODEL_KEYS, f"{where} [model]")
    floating_base = _flag(model, "floating_base", False, f"{where} [model]")
    imu_frame = model.get("imu_frame")
    if imu_frame is not None and not (isinstance(imu_frame, str) and imu_frame):
        raise RobotDescriptionError(f"{where} [model]: 'imu_frame' should be a link name, got {imu_frame!r}")
    urdf_path = _resolve_model_path(_at(f"{where} [model]").require(model, "urdf", str), config_path)
    urdf_limits = _urdf_joint_limits(urdf_path, config_path)

    joint_table = _at(where).require(config, "joints", dict)
    if not joint_table:
        raise RobotDescriptionError(f"{where}: [joints] is empty")
    joints = []
    for name, spec in joint_table.items():
        if not isinstance(spec, dict):
            raise RobotDescriptionError(f"{where}: joint {name!r} should be a table, got {spec!r}")
        if name not in urdf_limits:
            raise RobotDescriptionError(
                f"{where}: joint {name!r} is listed in the config but the model {urdf_path.name} has no such movable joint"
            )
        _refuse_unknown(spec, JOINT_KEYS, f"{where} joint {name!r}")
        lower, upper, effort, velocity = urdf_limits[name]
        joint = JointSpec(
            name=name,
            lower=lower,
            upper=upper,
            effort=effort,
            velocity=velocity,
            default=_at(f"{where} joint {name!r}").number(spec, "default", 0.0),
            kp=_at(f"{where} joint {name!r}").number(spec, "kp", 0.0),
            kd=_at(f"{where} joint {name!r}").number(spec, "kd", 0.0),
            armature=_at(f"{where} joint {name!r}").number(spec, "armature", 0.0),
            actuated=_flag(spec, "actuated", True, f"{where} joint {name!r}"),
        )
        if min(joint.kp, joint.kd, joint.armature) < 0:
            raise RobotDescriptionError(f"{where}: joint {name!r} has a negative gain or armature")
        if not joint.unbounded and not lower <= joint.default <= upper:
            raise RobotDescriptionError(f"{where}: joint {name!r} default {joint.default} is outside its limits [{lower}, {upper}]")
        joints.append(joint)
    missing = [name for name in urdf_limits if name not in joint_table]
    if missing:
        raise RobotDescriptionError(f"{where}: the model has joints the config does not list: {missing}")

    contacts = []
    contact_tables = config.get("contacts", [])
    if not isinstance(contact_tables, list) or not all(isinstance(t, dict) for t in contact_tables):
        raise RobotDescriptionError(f"{where}: 'contacts' should be an array of tables ([[contacts]])")
    for index, table in enumerate(contact_tables):
        cwhere = f"{where} [[contacts]] #{index}"
        _refuse_unknown(table, CONTACT_KEYS, cwhere)
        center = _at(cwhere).require(table, "center", list)
        if len(center) != 3:
            raise RobotDescriptionError(f"{cwhere}: 'center' needs 3 numbers, got {center!r}")
        contact = ContactRectangle(
            name=_at(cwhere).require(table, "name", str),
            link=_at(cwhere).require(table, "link", str),
            center=tuple(float(c) for c in center),
            half_length=_at(cwhere).number(table, "half_length", 0.0),
            half_width=_at(cwhere).number(table, "half_width", 0.0),
        )
        if contact.half_length <= 0 or contact.half_width <= 0:
            raise RobotDescriptionError(f"{cwhere}: half_length and half_width must be > 0")
        if "sole" in table:
            contact = replace(contact, sole=_sole_points(table["sole"], contact, cwhere))
        contacts.append(contact)

    collision, self_collision, exclude = _parse_collision(config, where, urdf_path, contacts)

    simulation = _table(config, "simulation", where, SIMULATION_KEYS)
    integrator = simulation.get("integrator", "implicitfast")
    if integrator not in ("euler", "implicit", "implicitfast", "rk4"):
        raise RobotDescriptionError(f"{where}: unknown integrator {integrator!r}")
    description = RobotDescription(
        name=_at(where).require(config, "name", str),
        folder=config_path.parent,
        urdf_path=urdf_path,
        floating_base=floating_base,
        base_link=_at(f"{where} [model]").require(model, "base_link", str),
        joints=tuple(joints),
        contacts=tuple(contacts),
        collision=collision,
        self_collision=self_collision,
        collision_exclude=exclude,
        imu_frame=imu_frame,
        timestep=_at(f"{where} [simulation]").number(simulation, "timestep", 0.002),
        integrator=integrator,
        floor_friction=_at(f"{where} [simulation]").number(simulation, "floor_friction", 1.0),
        description=str(config.get("description", "")),
    )
    if description.timestep <= 0:
        raise RobotDescriptionError(f"{where}: timestep must be > 0")
    links = {link.get("name") for link in ET.parse(urdf_path).getroot().iter("link")}
    for label, link in [("base_link", description.base_link), ("imu_frame", description.imu_frame)] + [
        (f"contact {c.name!r} link", c.link) for c in contacts
    ]:
        if link is not None and link not in links:
            raise RobotDescriptionError(f"{where}: {label} {link!r} is not a link of {urdf_path.name}")
    return description


def _parse_collision(
    config: dict[str, Any], where: str, urdf_path: Path, contacts: list[ContactRectangle]
) -> tuple[tuple[CollisionShape, ...], bool, tuple[tuple[str, str], ...]]:
    """``[[collision]]`` shapes and the ``[self_collision]`` table."""
    tables = config.get("collision", [])
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise RobotDescriptionError(f"{where}: 'collision' should be an array of tables ([[collision]])")
    shapes: list[CollisionShape] = []
    if tables:
        try:
            urdf = UrdfGeometry.parse(urdf_path, _resolve_package_uris(urdf_path.read_text()))
            shapes = [parse_shape(table, f"{where} [[collision]] #{i}", urdf) for i, table in enumerate(tables)]
        except CollisionError as error:
            raise RobotDescriptionError(str(error)) from error
    names = [s.name for s in shapes] + [f"{c.name}_sole" for c in contacts]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise RobotDescriptionError(f"{where}: collision shape names must be unique (give 'name'); repeated: {duplicates}")

    table = config.get("self_collision", {})
    if not isinstance(table, dict):
        raise RobotDescriptionError(f"{where}: [self_collision] should be a table")
    unknown = set(table) - {"enabled", "exclude"}
    if unknown:
        raise RobotDescriptionError(f"{where} [self_collision]: unknown keys {sorted(unknown)}")
    enabled = table.get("enabled", True)
    if not isinstance(enabled, bool):
        raise RobotDescriptionError(f"{where} [self_collision]: 'enabled' should be true or false, got {enabled!r}")
    carriers = {c.link for c in contacts} | {s.link for s in shapes}
    exclude = []
    for pair in table.get("exclude", []):
        if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(p, str) for p in pair)):
            raise RobotDescriptionError(f"{where} [self_collision]: 'exclude' entries should be pairs of link names, got {pair!r}")
        bare = [p for p in pair if p not in carriers]
        if bare:
            raise RobotDescriptionError(f"{where} [self_collision]: exclude pair {pair} names links without collision shapes: {bare}")
        exclude.append((pair[0], pair[1]))
    return tuple(shapes), enabled, tuple(exclude)
