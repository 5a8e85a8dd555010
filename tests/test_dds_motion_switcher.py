"""The hand-over of the G1's locomotion service through Unitree's motion switcher (DDS RPC,
``unitree_api`` Request_ / Response_), on loopback: the wire format against messages built by hand
from the public IDL, release and restore against the DDS emulator's service, and a service that
refuses or does not answer stopping ``giwbc deploy --release-service`` (exit 2, one line) before
any motor is enabled."""

from __future__ import annotations

import json
import struct
import time

import pytest

pytest.importorskip("cyclonedds")

from giwbc.apps.deploy import DeployOptions, deploy
from giwbc.apps.deploy_dds import EMULATED_SERVICE
from giwbc.emulation.dds_emulator import DdsEmulatorProcess, DdsFault
from giwbc.errors import DdsLinkError, HardwareConfigError
from giwbc.hal.dds.api_idl import Request_, Response_
from giwbc.hal.dds.motion_switcher import (
    CHECK_MODE,
    RELEASE_MODE,
    RPC_ERR_CLIENT_API_TIMEOUT,
    SELECT_MODE,
    MotionSwitcherClient,
    request,
    response,
)
from giwbc.hal.dds.robot import DdsRobot
from giwbc.hal.dds.transport import LOWCMD_TOPIC, LOWSTATE_TOPIC, DdsTransport
from giwbc.hal.hardware import load_hardware
from giwbc.hal.safety import SafetyConfig
from giwbc.runlog import read_log
from giwbc.runtimes.phases import StartupConfig

XCDR1_LE = b"\x00\x01\x00\x00"  # the encapsulation header: plain CDR (XCDR1), little endian


def _string(text: str, offset: int) -> tuple[bytes, int]:
    """A CDR string at ``offset`` (after padding to 4): uint32 length with the NUL, the bytes, NUL."""
    pad = b"\x00" * (-offset % 4)
    raw = text.encode() + b"\x00"
    out = pad + struct.pack("<I", len(raw)) + raw
    return out, offset + len(out)


def _request_by_hand(identity: int, api_id: int, parameter: str, lease: int = 0, priority: int = 0, noreply: bool = False) -> bytes:
    # RequestHeader_ { RequestIdentity_ {int64 id; int64 api_id}; RequestLease_ {int64 id}; RequestPolicy_ {int32 priority; boolean noreply} }
    body = struct.pack("<qqqi?", identity, api_id, lease, priority, noreply)  # offsets 0, 8, 16, 24, 28
    text, offset = _string(parameter, len(body))
    body += text
    body += b"\x00" * (-offset % 4) + struct.pack("<I", 0)  # sequence<octet> binary: empty
    return XCDR1_LE + body


def _response_by_hand(identity: int, api_id: int, code: int, data: str) -> bytes:
    # ResponseHeader_ { RequestIdentity_ {int64 id; int64 api_id}; ResponseStatus_ {int32 code} }; string data; sequence<octet> binary
    body = struct.pack("<qqi", identity, api_id, code)
    text, offset = _string(data, len(body))
    body += text + b"\x00" * (-offset % 4) + struct.pack("<I", 0)
    return XCDR1_LE + body


@pytest.mark.parametrize("api_id, parameter", [(CHECK_MODE, {}), (RELEASE_MODE, {}), (SELECT_MODE, {"name": "ai"})])
def test_requests_match_the_idl_built_by_hand(api_id: int, parameter: dict) -> None:
    identity = 1_700_000_000_123_456_789  # a monotonic-ns id, as the SDK's (8 bytes: its alignment shows)
    message = request(identity, api_id, parameter)
    wire = message.serialize(use_version_2=False)
    assert wire == _request_by_hand(identity, api_id, json.dumps(parameter))
    back = Request_.deserialize(wire)
    assert back.header.identity.id == identity and back.header.identity.api_id == api_id and json.loads(back.parameter) == parameter
    assert back.header.lease.id == 0 and back.header.policy.priority == 0 and back.header.policy.noreply is False


def test_a_response_built_by_hand_is_read_field_by_field() -> None:
    data = json.dumps({"form": "0", "name": "ai"})
    wire = _response_by_hand(42, CHECK_MODE, 0, data)
    got = Response_.deserialize(wire)
    assert (got.header.identity.id, got.header.identity.api_id, got.header.status.code, got.data, list(got.binary)) == (42, CHECK_MODE, 0, data, [])
    # and the emulator's answer to a request serialises to the same bytes (identity echoed)
    assert response(request(42, CHECK_MODE, {}), 0, data).serialize(use_version_2=False) == wire
    refused = response(request(7, RELEASE_MODE, {}), 3202).serialize(use_version_2=False)
    assert refused == _response_by_hand(7, RELEASE_MODE, 3202, "")


def _emulator(g1, **kwargs) -> DdsEmulatorProcess:
    plan = load_hardware(g1.folder / "hardware_dds.toml", 500.0, joint_names=g1.joint_names, allow_dds=True)
    motors = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    return DdsEmulatorProcess(plan, motors, g1, **kwargs)


def _foreign(listener: DdsTransport, seconds: float) -> int:
    time.sleep(seconds)
    return listener.foreign(1000)


def test_release_and_select_against_the_emulated_service(g1) -> None:
    with _emulator(g1, service="ai") as emulator:
        domain = emulator.plan.domain
        listener = DdsTransport(domain, "lo", publish=LOWCMD_TOPIC, subscribe=LOWSTATE_TOPIC, listen=True)
        try:
            with MotionSwitcherClient(domain, "lo") as switcher:
                assert switcher.check_mode().name == "ai"
                listener.foreign(1000)
                assert _foreign(listener, 0.1) >= 5  # the service commands the motors (~50 in 0.1 s; the listener keeps the last 8)
                released = switcher.release(timeout=3.0, interval=0.05)
                assert released.name == "ai" and not switcher.check_mode().active
                listener.foreign(1000)  # (what was in flight)
                assert _foreign(listener, 0.1) == 0  # released: nobody else publishes rt/lowcmd
                assert switcher.select("ai").name == "ai"
                listener.foreign(1000)
                assert _foreign(listener, 0.1) >= 5  # selected again: the service commands again
                assert [name for name, code in switcher.calls if code] == []
        finally:
            listener.close()
    assert emulator.counters["releases"] == 1 and emulator.counters["selects"] == 1
    assert emulator.counters["commands"] == 0  # the service's commands never reached the emulated firmware


def test_an_active_service_still_refuses_the_start_without_release(g1) -> None:
    """No --release-service: the robot's service publishing rt/lowcmd stops the start-up, as before."""
    with _emulator(g1, service="ai") as emulator:
        plan = emulator.host_plan()
        with pytest.raises(HardwareConfigError, match="locomotion service is still active"):
            DdsRobot(g1, plan)


@pytest.mark.parametrize("fault, message", [
    ("service_refuses", "is still active after"),
    ("service_mute", "did not answer CheckMode"),
])  # fmt: skip
def test_a_service_not_released_is_a_one_line_error(g1, fault: str, message: str) -> None:
    with _emulator(g1, service="ai", faults=(DdsFault(fault),)) as emulator:
        with MotionSwitcherClient(emulator.plan.domain, "lo", timeout=0.3) as switcher:
            with pytest.raises(DdsLinkError, match=message) as error:
                switcher.release(timeout=0.5, interval=0.05)
            assert "\n" not in str(error.value)


STARTUP = StartupConfig(settle_time=0.05, ramp_time=0.3, shutdown_time=0.1, off_delay=0.05)
TOLERANT = SafetyConfig(max_missing_cycles=25, imu_timeout_cycles=50, damping_time=0.1)


def _options(tmp_path, **overrides) -> DeployOptions:
    values = dict(emulate=True, emulator_mode="process", controller="pd", seconds=0.5, log=str(tmp_path / "run.mcap"), startup=STARTUP,
                  safety=TOLERANT, transport="dds", release_service=True, service_timeout=1.0)  # fmt: skip
    return DeployOptions(**{**values, **overrides})


@pytest.mark.slow
def test_release_run_and_restore_end_to_end(g1, tmp_path) -> None:
    said: list[str] = []
    outcome = deploy(_options(tmp_path, restore_service=True), description=g1, out=said.append)
    assert outcome.exit_code == 0, outcome.message
    assert outcome.result.ok and outcome.result.cycles > 200
    counters = outcome.emulator.counters
    assert counters["releases"] == 1 and counters["selects"] == 1 and counters["commands"] > 0
    log = read_log(outcome.log_path)
    assert not log.faults and log.event_names()[-1] == "motors_off"
    assert any(f"mode {EMULATED_SERVICE!r} released" in line for line in said)
    assert any(f"mode {EMULATED_SERVICE!r} selected again" in line for line in said)


@pytest.mark.parametrize("fault, message", [
    ("service_refuses", "is still active after"),
    ("service_mute", "did not answer CheckMode"),
])  # fmt: skip
def test_deploy_refuses_to_start_when_the_service_is_not_released(g1, tmp_path, fault: str, message: str) -> None:
    outcome = deploy(_options(tmp_path, faults=(DdsFault(fault),)), description=g1, out=None)
    assert outcome.exit_code == 2 and message in outcome.message and "\n" not in outcome.message
    assert outcome.result is None  # the runtime never ran: no motor enabled
    assert outcome.emulator is None or outcome.emulator.counters.get("commands", 0) == 0


def test_restore_needs_release_and_dds() -> None:
    with pytest.raises(ValueError, match="give both"):
        DeployOptions(transport="dds", restore_service=True)
    with pytest.raises(ValueError, match="need --transport dds"):
        DeployOptions(release_service=True)


def test_the_clients_request_on_the_wire_is_the_idl_built_by_hand() -> None:
    """What the client publishes (the serialized sample DDS carries, taken raw) is the hand-built XCDR1 request."""
    from cyclonedds._clayer import ddspy_take
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from giwbc.hal.dds.motion_switcher import REQUEST_TOPIC, RpcEndpoint

    domain = 227  # (a domain no other test uses; loopback)
    holder = RpcEndpoint(domain, "lo", server=True)  # creates the domain on loopback (giwbc's configuration)
    participant = DomainParticipant(domain)
    qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(4), Policy.DataRepresentation(use_cdrv0_representation=True))
    raw = DataReader(participant, Topic(participant, REQUEST_TOPIC, Request_), qos=qos)
    try:
        with MotionSwitcherClient(domain, "lo", timeout=0.2, resend=1.0) as switcher:  # (one request)
            time.sleep(0.1)
            holder.take()
            raw_before = ddspy_take(raw._ref, 0xFFFFFFFF, 16)
            assert isinstance(raw_before, int) or not raw_before
            assert switcher.call(CHECK_MODE, {})[0] == RPC_ERR_CLIENT_API_TIMEOUT  # (nobody answers here)
            identity = switcher._next_id
        got = ddspy_take(raw._ref, 0xFFFFFFFF, 16)
        assert not isinstance(got, int) and got, "no request on the wire"
        data = [d for d, info in got if info.valid_data][0]
        assert bytes(data) == _request_by_hand(identity, CHECK_MODE, "{}")
    finally:
        participant.__del__()
        holder.close()


def test_no_motion_switcher_on_the_network_is_one_line() -> None:
    with pytest.raises(DdsLinkError, match="no motion switcher service: nobody reads rt/api/motion_switcher/request") as error:
        MotionSwitcherClient(226, "lo", discovery=0.3)  # (a domain nobody uses, loopback)
    assert "\n" not in str(error.value)
