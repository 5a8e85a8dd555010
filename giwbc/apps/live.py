"""Live Foxglove: a loopback WebSocket server (the ``foxglove-sdk`` package, the ``foxglove`` extra)
for the scene's channels (:mod:`giwbc.apps.scene`), and a publisher process for simulations.

``giwbc deploy --foxglove``: the server lives in the run logger's process, which already decodes
every cycle (:class:`giwbc.apps.scene.SceneChannels` as the log's extension): nothing is added to
the control loop's thread or CPU. ``giwbc walk --foxglove``: the simulation hands its state at the
live rate to a :class:`ScenePublisher` process (a non-blocking datagram; one the publisher has no
room for is dropped), which does the kinematics and serves the viewer.

Open Foxglove, "Open connection", ``ws://127.0.0.1:8765`` (the port given), then a 3D panel.
"""

from __future__ import annotations

import json
import socket
import struct
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from giwbc.apps.scene import SceneChannels
from giwbc.errors import UnavailableError
from giwbc.robot.description import RobotDescription
from giwbc.runlog import RobotState
from giwbc.util import children

DEFAULT_PORT = 8765
HOST = "127.0.0.1"  # loopback only: nothing of the robot leaves the machine


def require_foxglove() -> Any:
    """The foxglove-sdk module, or a one-line error."""
    try:
        import foxglove  # optional dependency (the `foxglove` extra)
    except ImportError as error:
        raise UnavailableError("--foxglove needs the foxglove-sdk package: pip install 'giwbc[foxglove]'") from error
    return foxglove


def _serve_file(uri: str) -> bytes | None:
    """Assets the viewer asks for: the meshes the URDF names as ``file://`` paths."""
    if not uri.startswith("file://"):
        return None
    path = Path(uri[len("file://"):])
    return path.read_bytes() if path.suffix.lower() in (".stl", ".dae", ".obj", ".glb", ".gltf") and path.is_file() else None


class LiveServer:
    """A Foxglove WebSocket server on loopback; :meth:`start` where it should run (its threads are not forked)."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = HOST) -> None:
        require_foxglove()  # said before any run starts
        self.port, self.host = int(port), host
        self._server: Any = None
        self._context: Any = None
        self._channels: dict[str, Any] = {}

    def start(self, schemas: Mapping[str, Mapping[str, Any]]) -> None:
        foxglove = require_foxglove()
        context = self._context = foxglove.Context()  # kept: its channels close when it goes
        self._server = foxglove.start_server(name="giwbc", host=self.host, port=self.port, context=context, asset_handler=_serve_file)
        self._channels = {
            topic: foxglove.Channel(topic, schema=foxglove.Schema(name=schema["title"], encoding="jsonschema",
                                                                  data=json.dumps(schema).encode()),
                                    message_encoding="json", context=context)
            for topic, schema in schemas.items()
        }  # fmt: skip

    def publish(self, topic: str, t: float, payload: str) -> None:
        self._channels[topic].log(payload.encode(), log_time=max(0, int(round(t * 1e9))))

    def stop(self) -> None:
        if self._server is not None:
            self._server.stop()
            self._server = None


# --- a simulation's side ------------------------------------------------------------------------------
_STATE = struct.Struct("=dII")  # time, joints, contacts; then q, tau, base position, quaternion, flags, forces


class ScenePublisher:
    """Streams a simulation to Foxglove from a process of its own: :meth:`send` packs the state in
    one datagram (never blocks: dropped if the publisher is behind); the child computes and serves."""

    def __init__(self, description: RobotDescription, *, port: int = DEFAULT_PORT, rate: float = 30.0) -> None:
        self.channels = SceneChannels(description, rate=rate, live=LiveServer(port), live_rate=rate, log=False)
        self.rate = rate
        self.dropped = 0
        self._sock, child = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self._process = children.start(_publish, (child, self._sock, self.channels), "giwbc-foxglove")
        child.close()
        self._sock.setblocking(False)

    def send(self, t: float, q: np.ndarray, tau: np.ndarray | None, base_position: np.ndarray | None, base_quaternion: np.ndarray | None,
             contacts: np.ndarray | None = None, contact_forces: np.ndarray | None = None) -> None:  # fmt: skip
        n, k = len(q), 0 if contacts is None else len(contacts)
        parts = [_STATE.pack(float(t), n, k), np.asarray(q, float).tobytes(),
                 (np.full(n, np.nan) if tau is None else np.asarray(tau, float)).tobytes(),
                 (np.full(3, np.nan) if base_position is None else np.asarray(base_position, float)).tobytes(),
                 (np.full(4, np.nan) if base_quaternion is None else np.asarray(base_quaternion, float)).tobytes()]  # fmt: skip
        if k:
            parts += [np.asarray(contacts, bool).tobytes(),
                      (np.full((k, 3), np.nan) if contact_forces is None else np.asarray(contact_forces, float)).tobytes()]
        try:
            self._sock.send(b"".join(parts))
        except BlockingIOError:
            self.dropped += 1

    def close(self) -> None:
        self._sock.close()  # the child sees the end and stops its server
        children.stop(self._process, 5.0)

    def __enter__(self) -> ScenePublisher:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _decode(data: bytes) -> RobotState:
    t, n, k = _STATE.unpack_from(data)
    values = np.frombuffer(data, dtype=float, count=2 * n + 7, offset=_STATE.size)
    state = RobotState(t, values[:n].copy(), values[n : 2 * n].copy(), values[2 * n : 2 * n + 3].copy(), values[2 * n + 3 :].copy())
    if not np.isfinite(state.tau).all():
        state.tau = None
    if k:
        offset = _STATE.size + 8 * (2 * n + 7)
        state.contacts = np.frombuffer(data, dtype=bool, count=k, offset=offset).copy()
        forces = np.frombuffer(data, dtype=float, count=3 * k, offset=offset + k).reshape(k, 3)
        state.contact_forces = forces.copy() if np.isfinite(forces).all() else None
    return state


def _publish(sock: socket.socket, parent_end: socket.socket, channels: SceneChannels) -> None:
    """The publisher process: serve the viewer until the simulation closes its end."""
    parent_end.close()
    channels.open()
    try:
        while data := sock.recv(1 << 16):
            channels.update(_decode(data))
    finally:
        channels.close()


# --- a viewer's side (checks, benchmarks) ------------------------------------------------------------
_MESSAGE_DATA = 0x01  # binary opcode of a message (then u32 subscription id, u64 log time, payload)


def watch(port: int, seconds: float, *, host: str = HOST, connect_within: float = 30.0,
          topics: tuple[str, ...] | None = None) -> dict[str, list[tuple[int, str]]]:  # fmt: skip
    """Be a Foxglove viewer for ``seconds`` (or until the server goes): connect (retrying for
    ``connect_within`` s while the server starts), subscribe to every advertised channel (or
    ``topics``) and return ``topic -> [(log time ns, JSON text)]`` as received. Needs ``websockets``."""
    try:
        from websockets.exceptions import ConnectionClosed  # optional (the `foxglove` extra)
        from websockets.sync.client import connect
    except ImportError as error:
        raise UnavailableError("watching a Foxglove server needs the websockets package") from error
    deadline = time.monotonic() + connect_within
    while True:
        try:
            connection = connect(f"ws://{host}:{port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],  # type: ignore[list-item]
                                 open_timeout=2.0, max_size=None)  # fmt: skip
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
    received: dict[str, list[tuple[int, str]]] = {}
    subscriptions: dict[int, str] = {}
    end = time.monotonic() + seconds
    with connection:
        while (left := end - time.monotonic()) > 0:
            try:
                message = connection.recv(timeout=left)
            except (TimeoutError, ConnectionClosed):
                break
            if isinstance(message, str):
                op = json.loads(message)
                if op.get("op") == "advertise":
                    new = [c for c in op["channels"] if topics is None or c["topic"] in topics]
                    for channel in new:
                        subscriptions[int(channel["id"])] = channel["topic"]
                    if new:
                        connection.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": int(c["id"]), "channelId": int(c["id"])} for c in new]}))  # fmt: skip
            elif message and message[0] == _MESSAGE_DATA:
                subscription, log_time = struct.unpack_from("<IQ", message, 1)
                topic = subscriptions.get(subscription)
                if topic is not None:
                    received.setdefault(topic, []).append((log_time, bytes(message[13:]).decode()))
    return received


def main(argv: list[str] | None = None) -> int:
    """``python -m giwbc.apps.live PORT SECONDS``: watch a server, print messages per topic (JSON)."""
    args = sys.argv[1:] if argv is None else argv
    received = watch(int(args[0]), float(args[1]))
    print(json.dumps({topic: len(messages) for topic, messages in received.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
