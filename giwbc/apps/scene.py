"""The robot in 3D for Foxglove: the robot description, link transforms, joint states and contact
forces, as JSON messages with well-known schemas, for a run log and for a live viewer.

Channels (JSON; the schema names are the ones Foxglove's 3D panel understands):

======================  ===================================================================
``/robot_description``  the URDF (``std_msgs/String``: ``data``), mesh paths made absolute
``/tf``                 ``foxglove.FrameTransforms``: world -> base from the base estimate
                        (pose), then every URDF link from its URDF parent link (Pinocchio
                        forward kinematics of the measured joint positions)
``/joint_states``       ``giwbc.JointStates``: names, measured positions and torques
``/contact_forces``     ``foxglove.SceneUpdate``: one arrow per foot in contact, from the foot
                        along the force (0.5 mm per N); the simulator's forces when known,
                        else a quasi-static estimate from the measured torques:
                        ``J_c^T f = g(q) - S^T tau`` in least squares over all the DoFs
======================  ===================================================================

:class:`SceneChannels` adds these channels to a run log (a :class:`giwbc.runlog.LogExtension`,
computed in the logger process at ``rate`` Hz) and, with a :class:`giwbc.apps.live.LiveServer`,
streams them to Foxglove at ``live_rate`` Hz.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pinocchio as pin

from giwbc.robot.description import RobotDescription
from giwbc.runlog import RobotState
from giwbc.runlog.extension import Message

WORLD = "world"
NEWTONS_TO_METRES = 0.0005  # arrow length per newton
GRAVITY = 9.81

_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}, "required": ["sec", "nsec"]}
_VECTOR3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}, "required": list("xyz")}
_QUATERNION = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}, "required": list("xyzw")}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in "rgba"}, "required": list("rgba")}
_POSE = {"type": "object", "properties": {"position": _VECTOR3, "orientation": _QUATERNION}, "required": ["position", "orientation"]}
_PRIMITIVES = ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")
_ARROW = {
    "type": "object",
    "properties": {"pose": _POSE, **{k: {"type": "number"} for k in ("shaft_length", "shaft_diameter", "head_length", "head_diameter")},
                   "color": _COLOR},
    "required": ["pose", "shaft_length", "shaft_diameter", "head_length", "head_diameter", "color"],
}  # fmt: skip

SCHEMAS: Mapping[str, dict[str, Any]] = {
    "/robot_description": {"title": "std_msgs/String", "type": "object", "properties": {"data": {"type": "string"}}, "required": ["data"]},
    "/tf": {
        "title": "foxglove.FrameTransforms", "type": "object", "required": ["transforms"],
        "properties": {"transforms": {"type": "array", "items": {
            "type": "object", "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
            "properties": {"timestamp": _TIME, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
                           "translation": _VECTOR3, "rotation": _QUATERNION},
        }}},
    },
    "/joint_states": {
        "title": "giwbc.JointStates", "type": "object", "required": ["timestamp", "name", "position", "effort"],
        "properties": {"timestamp": _TIME, "name": {"type": "array", "items": {"type": "string"}},
                       "position": {"type": "array", "items": {"type": "number"}}, "effort": {"type": "array", "items": {"type": "number"}}},
    },
    "/contact_forces": {
        "title": "foxglove.SceneUpdate", "type": "object", "required": ["deletions", "entities"],
        "properties": {"deletions": {"type": "array"}, "entities": {"type": "array", "items": {
            "type": "object", "required": ["timestamp", "frame_id", "id", "lifetime", "frame_locked", "metadata", *_PRIMITIVES],
            "properties": {"timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"}, "lifetime": _TIME,
                           "frame_locked": {"type": "boolean"}, "metadata": {"type": "array"},
                           "arrows": {"type": "array", "items": _ARROW},
                           **{k: {"type": "array"} for k in _PRIMITIVES[1:]}},
        }}},
    },
}  # fmt: skip


def stamp(t: float) -> dict[str, int]:
    """A Foxglove time from seconds."""
    ns = max(0, int(round(t * 1e9)))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _rotation_to(direction: np.ndarray) -> np.ndarray:
    """The quaternion (x, y, z, w) turning +x onto ``direction``."""
    d = direction / max(np.linalg.norm(direction), 1e-12)
    axis = np.cross([1.0, 0.0, 0.0], d)
    s, c = np.linalg.norm(axis), float(d[0])
    if s < 1e-9:
        return np.array([0.0, 0.0, 1.0, 0.0]) if c < 0 else np.array([0.0, 0.0, 0.0, 1.0])
    half = math.atan2(s, c) / 2
    return np.append(axis / s * math.sin(half), math.cos(half))


def urdf_tree(urdf: str) -> dict[str, str]:
    """``child link -> parent link`` of every URDF joint."""
    root = ET.fromstring(urdf)
    return {j.find("child").get("link"): j.find("parent").get("link") for j in root.iter("joint")}  # type: ignore[union-attr]


def absolute_mesh_paths(urdf: str, urdf_path: Path) -> str:
    """The URDF with ``package://`` and relative mesh paths turned into ``file://`` absolute ones
    (Foxglove reads local files; a package path it cannot resolve)."""
    def resolve(match: re.Match[str]) -> str:
        uri = match.group(1)
        if uri.startswith("package://"):
            package, _, rest = uri[len("package://"):].partition("/")
            for parent in urdf_path.parents:
                if parent.name == package or (parent / package).is_dir():
                    base = parent if parent.name == package else parent / package
                    if (base / rest).exists():
                        return f'filename="file://{(base / rest).resolve()}"'
            return match.group(0)
        if "://" in uri:
            return match.group(0)
        return f'filename="file://{(urdf_path.parent / uri).resolve()}"'

    return re.sub(r'filename="([^"]+)"', resolve, urdf)


class LiveSink(Protocol):
    """Where live messages go (a Foxglove WebSocket server)."""

    def start(self, schemas: Mapping[str, Mapping[str, Any]]) -> None: ...

    def publish(self, topic: str, t: float, payload: str) -> None: ...

    def stop(self) -> None: ...


class RobotScene:
    """Forward kinematics and contact forces of one robot, as the scene's JSON messages."""

    def __init__(self, description: RobotDescription, joint_names: Sequence[str] | None = None) -> None:
        self.description = description
        self.model = description.pinocchio_model
        self.data = self.model.createData()
        self.floating = description.floating_base
        names = tuple(joint_names) if joint_names is not None else description.joint_names
        unknown = set(names) - set(description.joint_names)
        if unknown:
            raise ValueError(f"joints {sorted(unknown)} are not {description.name}'s")
        self.joint_names = names
        offset = 7 if self.floating else 0
        self._index = np.array([offset + description.joint_names.index(n) for n in names], dtype=int)
        self._torque_index = self._index - (1 if self.floating else 0)  # velocity-space rows of the joints
        self.parents = urdf_tree(description.urdf_text())
        bodies = {f.name for f in self.model.frames if f.type == pin.FrameType.BODY}
        self.links = [link for link in self.parents if link in bodies]
        self.root = description.base_link
        self._frame = {link: self.model.getFrameId(link, pin.FrameType.BODY) for link in [self.root, *self.links]}
        self.contacts = description.contacts
        self._contact_frames = [self.model.getFrameId(c.link, pin.FrameType.BODY) for c in self.contacts]
        self._contact_points = [np.asarray(c.center, dtype=float) for c in self.contacts]
        self.urdf = absolute_mesh_paths(description.urdf_text(), Path(description.urdf_path))
        self._q = pin.neutral(self.model)
        if self.floating:
            self._q[:3] = description.default_base_position
        self._last_forces: np.ndarray | None = None

    # --- kinematics --------------------------------------------------------------------------------
    def configuration(self, state: RobotState) -> np.ndarray:
        """Pinocchio's q from the state (missing parts: the last known ones)."""
        q = self._q
        if state.q is not None:
            q[self._index] = np.nan_to_num(state.q, nan=0.0)
        if self.floating and state.base_position is not None and state.base_quaternion is not None:
            quaternion = np.asarray(state.base_quaternion, dtype=float)
            if np.all(np.isfinite(quaternion)) and np.linalg.norm(quaternion) > 0.5 and np.all(np.isfinite(state.base_position)):
                q[:3], q[3:7] = state.base_position, quaternion / np.linalg.norm(quaternion)
        return q

    def link_poses(self, q: np.ndarray) -> dict[str, pin.SE3]:
        """World pose of the root and every link."""
        pin.forwardKinematics(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        return {link: self.data.oMf[frame] for link, frame in self._frame.items()}

    def transforms(self, q: np.ndarray) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
        """``(parent, child, translation, quaternion xyzw)``: world -> root, then each link from its URDF parent."""
        poses = self.link_poses(q)
        out = [(WORLD, self.root, poses[self.root].translation.copy(), pin.Quaternion(poses[self.root].rotation).coeffs().copy())]
        for link in self.links:
            relative = poses[self.parents[link]].actInv(poses[link])
            out.append((self.parents[link], link, relative.translation.copy(), pin.Quaternion(relative.rotation).coeffs().copy()))
        return out

    def contact_forces(self, q: np.ndarray, state: RobotState) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """``(contact, world point, world force)`` of each contact in contact (kinematics already updated)."""
        if not self.contacts:
            return []
        flags = np.ones(len(self.contacts), bool) if state.contacts is None or len(state.contacts) != len(self.contacts) else state.contacts
        if state.contact_forces is not None:
            forces = np.asarray(state.contact_forces, dtype=float).reshape(len(self.contacts), 3)
        elif state.tau is not None and flags.any():
            forces = self._estimate_forces(q, np.nan_to_num(state.tau), flags)
        else:
            return []
        out = []
        for k, contact in enumerate(self.contacts):
            if flags[k] and np.linalg.norm(forces[k]) > 1e-6:
                point = self.data.oMf[self._contact_frames[k]].act(self._contact_points[k])
                out.append((contact.name, point, forces[k]))
        return out

    def _estimate_forces(self, q: np.ndarray, tau: np.ndarray, flags: np.ndarray) -> np.ndarray:
        """Quasi-static contact forces: least squares of ``J_c^T f = g(q) - S^T tau`` over the feet in contact."""
        gravity = pin.computeGeneralizedGravity(self.model, self.data, q)
        applied = np.zeros(self.model.nv)
        applied[self._torque_index] = tau
        pin.computeJointJacobians(self.model, self.data, q)
        active = np.flatnonzero(flags)
        jacobians = [pin.getFrameJacobian(self.model, self.data, self._contact_frames[k], pin.LOCAL_WORLD_ALIGNED) for k in active]
        wrenches, *_ = np.linalg.lstsq(np.vstack(jacobians).T, gravity - applied, rcond=None)
        forces = np.zeros((len(self.contacts), 3))
        forces[active] = wrenches.reshape(len(active), 6)[:, :3]
        return forces

    # --- messages ----------------------------------------------------------------------------------
    def description_message(self) -> str:
        return json.dumps({"data": self.urdf})

    def messages(self, state: RobotState) -> list[Message]:
        """The ``/tf``, ``/joint_states`` and ``/contact_forces`` messages of one state."""
        q = self.configuration(state)
        time = stamp(state.t)
        tf = [{"timestamp": time, "parent_frame_id": parent, "child_frame_id": child,
               "translation": dict(zip("xyz", map(float, p))), "rotation": dict(zip("xyzw", map(float, r)))}
              for parent, child, p, r in self.transforms(q)]  # fmt: skip
        out: list[Message] = [("/tf", state.t, json.dumps({"transforms": tf}))]
        if state.q is not None:
            effort = [0.0] * len(self.joint_names) if state.tau is None else [float(x) for x in np.nan_to_num(state.tau)]
            out.append(("/joint_states", state.t, json.dumps({
                "timestamp": time, "name": list(self.joint_names), "position": [float(x) for x in np.nan_to_num(state.q)], "effort": effort,
            })))  # fmt: skip
        entities = []
        for name, point, force in self.contact_forces(q, state):
            entities.append({
                "timestamp": time, "frame_id": WORLD, "id": name, "lifetime": {"sec": 0, "nsec": 200_000_000}, "frame_locked": False,
                "metadata": [{"key": "force_N", "value": f"{np.linalg.norm(force):.1f}"}],
                "arrows": [{"pose": {"position": dict(zip("xyz", map(float, point))),
                                     "orientation": dict(zip("xyzw", map(float, _rotation_to(force))))},
                            "shaft_length": float(np.linalg.norm(force) * NEWTONS_TO_METRES), "shaft_diameter": 0.015,
                            "head_length": 0.04, "head_diameter": 0.035, "color": {"r": 0.9, "g": 0.3, "b": 0.1, "a": 0.9}}],
                **{k: [] for k in _PRIMITIVES[1:]},
            })  # fmt: skip
        out.append(("/contact_forces", state.t, json.dumps({"deletions": [], "entities": entities})))
        return out


class SceneChannels:
    """The scene's channels in a run log (a :class:`giwbc.runlog.LogExtension`) and, with ``live``,
    streamed live; every method runs where the state is decoded (the logger process), never in the loop."""

    def __init__(self, description: RobotDescription, joint_names: Sequence[str] | None = None, *, rate: float = 50.0,
                 live: LiveSink | None = None, live_rate: float = 30.0, log: bool = True) -> None:  # fmt: skip
        if not (rate > 0 and live_rate > 0):
            raise ValueError(f"scene rates must be > 0, got {rate} and {live_rate}")
        self.scene = RobotScene(description, joint_names)
        self.period, self.live_period = 1.0 / rate, 1.0 / live_rate
        self.live, self.log = live, log
        self._next_log = self._next_live = self._next_description = 0.0

    def schemas(self) -> Mapping[str, Mapping[str, Any]]:
        return SCHEMAS if self.log else {}

    def open(self) -> list[Message]:
        if self.live is not None:
            self.live.start(SCHEMAS)
        return [("/robot_description", 0.0, self.scene.description_message())] if self.log else []

    def update(self, state: RobotState) -> list[Message]:
        log_due = self.log and state.t >= self._next_log - 1e-9
        live_due = self.live is not None and state.t >= self._next_live - 1e-9
        if not (log_due or live_due):
            return []
        messages = self.scene.messages(state)
        if live_due:
            assert self.live is not None
            self._next_live = max(self._next_live + self.live_period, state.t + self.live_period / 2)
            if state.t >= self._next_description:  # a viewer that connects later gets the model too
                self.live.publish("/robot_description", state.t, self.scene.description_message())
                self._next_description = state.t + 2.0
            for topic, t, payload in messages:
                self.live.publish(topic, t, payload)
        if not log_due:
            return []
        self._next_log = max(self._next_log + self.period, state.t + self.period / 2)
        return messages

    def close(self) -> None:
        if self.live is not None:
            self.live.stop()
