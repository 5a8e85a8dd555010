"""The robot in 3D for Foxglove: a log written by an emulated deployment opens with the mcap
reader, every message of every channel validates against its channel's JSON schema, the transforms
chain from the world to every URDF link and put each link where Pinocchio's forward kinematics of
the logged state puts it, the contact arrows carry the robot's weight; a viewer connected over
loopback receives the same channels live during the deployment; a failing extension costs the log
nothing."""

from __future__ import annotations

import json
import socket
import threading

import numpy as np
import pinocchio as pin
import pytest

from giwbc.apps.deploy import DeployOptions, deploy
from giwbc.apps.live import ScenePublisher, watch
from giwbc.apps.scene import NEWTONS_TO_METRES, WORLD, urdf_tree
from giwbc.hal.safety import SafetyConfig
from giwbc.runlog import SCHEMAS, RobotState, RunLogWriter, read_log
from giwbc.runtimes.phases import StartupConfig

jsonschema = pytest.importorskip("jsonschema")
SCENE_TOPICS = {"/robot_description", "/tf", "/joint_states", "/contact_forces"}


def _live_available() -> bool:
    try:
        import foxglove  # noqa: F401
        import websockets  # noqa: F401
    except ImportError:
        return False
    return True


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def deployment(g1, tmp_path_factory):
    """A 1 s emulated deployment (WBC standing) with the scene in its log and, when foxglove-sdk is
    there, streamed live to a viewer on loopback: the outcome and what the viewer received."""
    path = tmp_path_factory.mktemp("foxglove") / "run.mcap"
    live = _live_available()
    port = _free_port() if live else None
    received: dict = {}
    viewer = threading.Thread(target=lambda: received.update(watch(port, 60.0)), daemon=True) if live else None
    if viewer is not None:
        viewer.start()
    options = DeployOptions(
        emulate=True, controller="wbc", seconds=1.0, realtime=False, log=str(path), foxglove_port=port,
        startup=StartupConfig(settle_time=0.05, ramp_time=0.5, shutdown_time=0.3, off_delay=0.1),
        safety=SafetyConfig(max_stall=0.5),
    )  # fmt: skip
    outcome = deploy(options, model=g1.build_mujoco(), description=g1, out=None)
    if viewer is not None:
        viewer.join(30)  # the server stops with the log: the viewer's connection closes
    assert outcome.exit_code == 0, outcome.message
    return outcome, received if live else None


def _validate(schema: dict, payload: dict) -> None:
    jsonschema.validators.validator_for(schema, default=jsonschema.Draft202012Validator)(schema).validate(payload)


def _world_poses(transforms: list[dict]) -> dict[str, pin.SE3]:
    """Compose a FrameTransforms message from the world to every frame it reaches."""
    edges = {t["child_frame_id"]: t for t in transforms}
    poses: dict[str, pin.SE3] = {WORLD: pin.SE3.Identity()}

    def pose(frame: str, depth: int = 0) -> pin.SE3:
        if frame not in poses:
            assert depth < 100 and frame in edges, f"{frame} is not reachable from {WORLD}"
            edge = edges[frame]
            r, p = edge["rotation"], edge["translation"]
            local = pin.SE3(pin.Quaternion(r["w"], r["x"], r["y"], r["z"]).toRotationMatrix(), np.array([p["x"], p["y"], p["z"]]))
            poses[frame] = pose(edge["parent_frame_id"], depth + 1) * local
        return poses[frame]

    for child in edges:
        pose(child)
    return poses


def test_every_channel_of_the_log_validates_against_its_schema(deployment):
    from mcap.reader import make_reader

    outcome, _ = deployment
    counts: dict[str, int] = {}
    with open(outcome.log_path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            _validate(json.loads(schema.data), json.loads(message.data))
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert set(counts) >= (set(SCHEMAS) - {"/faults"}) | SCENE_TOPICS
    assert counts["/robot_description"] == 1
    robot_time = outcome.result.robot_time
    assert counts["/tf"] == pytest.approx(50 * robot_time, rel=0.15)  # 50 Hz, a tenth of the 500 Hz loop


def test_transforms_chain_to_every_link_where_pinocchio_puts_it(deployment, g1):
    outcome, _ = deployment
    log = read_log(outcome.log_path)
    links = set(urdf_tree(g1.urdf_text())) | {g1.base_link}
    assert "<robot" in log.topic("/robot_description")[0]["data"] and "package://" not in log.topic("/robot_description")[0]["data"]
    replies = {round(m["t"], 6): m for m in log.topic("/replies")}
    estimates = {round(m["t"], 6): m for m in log.topic("/estimator")}
    model, data = g1.pinocchio_model, g1.pinocchio_model.createData()
    checked = 0
    for message in log.topic("/tf"):
        poses = _world_poses(message["transforms"])
        assert links <= set(poses)  # every link reachable from the world
        stamp = message["transforms"][0]["timestamp"]
        t = round(stamp["sec"] + stamp["nsec"] * 1e-9, 6)
        if t not in replies or estimates.get(t, {}).get("position") is None:
            continue
        q = pin.neutral(model)
        q[:3], q[3:7], q[7:] = estimates[t]["position"], estimates[t]["quaternion"], replies[t]["q"]
        q[3:7] /= np.linalg.norm(q[3:7])
        pin.framesForwardKinematics(model, data, q)
        for link in ("left_ankle_roll_link", "right_wrist_yaw_link", "torso_link"):
            expected = data.oMf[model.getFrameId(link, pin.FrameType.BODY)]
            assert np.allclose(poses[link].translation, expected.translation, atol=2e-4)
            assert np.allclose(poses[link].rotation, expected.rotation, atol=2e-3)
        checked += 1
    assert checked >= 20


def test_contact_arrows_carry_the_weight_of_the_standing_robot(deployment, g1):
    outcome, _ = deployment
    log = read_log(outcome.log_path)
    running = [e["t"] for e in log.events if e["event"] == "phase" and e["detail"]["phase"] in ("running", "shutdown")]
    weight = g1.total_mass * 9.81
    checked = 0
    for message in log.topic("/contact_forces"):
        entities = message["entities"]
        if not entities:
            continue
        stamp = entities[0]["timestamp"]
        t = stamp["sec"] + stamp["nsec"] * 1e-9
        if not running[0] + 0.1 <= t <= running[1]:
            continue
        vertical = {}
        for entity in entities:
            arrow = entity["arrows"][0]
            o = arrow["pose"]["orientation"]
            direction = pin.Quaternion(o["w"], o["x"], o["y"], o["z"]).toRotationMatrix()[:, 0]
            vertical[entity["id"]] = arrow["shaft_length"] / NEWTONS_TO_METRES * direction[2]
        assert set(vertical) == {"left_foot", "right_foot"}
        assert sum(vertical.values()) == pytest.approx(weight, rel=0.03)
        assert all(0.3 * weight < f < 0.7 * weight for f in vertical.values())  # standing on both feet
        checked += 1
    assert checked >= 20


def test_a_viewer_on_loopback_receives_the_scene_live(deployment, g1):
    outcome, received = deployment
    if received is None:
        pytest.skip("foxglove-sdk or websockets is not installed: no live server")
    assert set(received) == SCENE_TOPICS
    assert "<robot" in json.loads(received["/robot_description"][0][1])["data"]
    transforms = received["/tf"]
    assert len(transforms) >= 0.5 * 30 * outcome.result.robot_time  # ~30 Hz while it ran (a late connection misses a few)
    links = set(urdf_tree(g1.urdf_text()))
    times = [log_time for log_time, _ in transforms]
    assert times == sorted(times)
    for _, payload in transforms[:: max(1, len(transforms) // 10)]:
        message = json.loads(payload)
        from giwbc.apps.scene import SCHEMAS as SCENE_SCHEMAS

        _validate(SCENE_SCHEMAS["/tf"], message)
        assert links <= set(_world_poses(message["transforms"]))


class _Broken:
    """An extension that fails on its third cycle."""

    def __init__(self) -> None:
        self.calls = 0

    def schemas(self):
        return {"/broken": {"title": "test.Broken", "type": "object"}}

    def open(self):
        return [("/broken", 0.0, "{}")]

    def update(self, state: RobotState):
        self.calls += 1
        if self.calls == 3:
            raise RuntimeError("viewer gone wrong")
        return [("/broken", state.t, json.dumps({"q0": float(state.q[0])}))]

    def close(self) -> None:
        pass


def test_a_failing_extension_costs_the_log_nothing(tmp_path):
    path = tmp_path / "broken.mcap"
    with RunLogWriter(path, ("a", "b"), extension=_Broken()) as log:
        for cycle in range(5):
            t = 0.002 * cycle
            log.replies(cycle, t, [cycle, 0], [0, 0], [0, 0], [30, 30], [0, 0], [False, False], 0, 0, 0)
            log.timing(cycle, t, cycle, 1.0, 2000.0, 500.0, 50.0, 50.0, False)
            log.flush()
    run = read_log(path)
    assert len(run.topic("/replies")) == len(run.topic("/timing")) == 5
    assert [m.get("q0") for m in run.topic("/broken")] == [None, 0.0, 1.0]  # open, then two cycles
    failed = [e for e in run.events if e["event"] == "log_extension_failed"]
    assert len(failed) == 1 and "viewer gone wrong" in failed[0]["detail"]["error"]


def test_a_simulation_streams_through_the_publisher_process(g1):
    if not _live_available():
        pytest.skip("foxglove-sdk or websockets is not installed")
    port = _free_port()
    q = g1.default_configuration()
    received: dict = {}
    with ScenePublisher(g1, port=port, rate=30.0) as publisher:
        viewer = threading.Thread(target=lambda: received.update(watch(port, 60.0)), daemon=True)
        viewer.start()
        lifted = q[:3] + [0.0, 0.0, 0.25]
        forces = np.array([[0.0, 0.0, 150.0], [0.0, 0.0, 170.0]])
        for k in range(200):  # 2 s: the viewer connects and subscribes meanwhile
            publisher.send(k / 30.0, q[7:], None, lifted, q[3:7], np.array([True, True]), forces)
            threading.Event().wait(0.01)
    viewer.join(30)
    assert publisher.dropped == 0
    message = json.loads(received["/tf"][-1][1])
    root = [t for t in message["transforms"] if t["parent_frame_id"] == WORLD][0]
    assert root["child_frame_id"] == g1.base_link and root["translation"]["z"] == pytest.approx(lifted[2])
    arrows = json.loads(received["/contact_forces"][-1][1])["entities"]
    lengths = sorted(e["arrows"][0]["shaft_length"] / NEWTONS_TO_METRES for e in arrows)
    assert lengths == pytest.approx([150.0, 170.0])  # the simulator's forces when given, not an estimate
