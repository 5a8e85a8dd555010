"""giwbc-unix: the python-can bus between processes (frames round-trip, timeouts, full buffer, closed peer)."""

from __future__ import annotations

import time
import uuid

import can
import pytest

from giwbc.hal.frames import frame_port, to_message
from giwbc.hal.unix_bus import UnixCanBus, channel_address


def _frames() -> list[can.Message]:
    return [
        can.Message(arbitration_id=0x7FF, data=bytes(range(8)), is_extended_id=False),
        can.Message(arbitration_id=0x1ABCDEF0 & 0x1FFFFFFF, data=b"\x01\x02\x03", is_extended_id=True),
        can.Message(arbitration_id=0x12, data=b"", is_extended_id=False),
        can.Message(arbitration_id=0x123, is_remote_frame=True, dlc=0, is_extended_id=False),
        can.Message(arbitration_id=0x4, data=bytes(8), is_error_frame=True, is_extended_id=False),
    ]


def _same(a: can.Message, b: can.Message) -> bool:
    return (a.arbitration_id, a.is_extended_id, a.is_remote_frame, a.is_error_frame, bytes(a.data)) == (
        b.arbitration_id, b.is_extended_id, b.is_remote_frame, b.is_error_frame, bytes(b.data))


def test_frames_round_trip_through_a_pair() -> None:
    host, motors = UnixCanBus.pair()
    try:
        for frame in _frames():
            host.send(frame)
            got = motors.recv(0.5)
            assert got is not None and _same(frame, got), (frame, got)
            motors.send(frame)  # and back
            assert _same(frame, host.recv(0.5))
        for frame in _frames():
            motors.send(frame)
        port = frame_port(host)  # the batch path reads the same datagrams
        got = [to_message(record) for record in port.receive(None).frames]
        assert [_same(a, b) for a, b in zip(_frames(), got)] == [True] * 5
        assert len(port.receive(None).frames) == 0
    finally:
        host.shutdown()
        motors.shutdown()


def test_python_can_opens_it_by_name_and_the_motor_side_accepts_the_host() -> None:
    channel = f"test-{uuid.uuid4().hex[:8]}"
    motors = can.Bus(interface="giwbc-unix", channel=channel, serve=True)
    try:
        assert isinstance(motors, UnixCanBus) and not motors.connected
        with pytest.raises(can.CanInitializationError, match="already served"):
            UnixCanBus(channel, serve=True)
        motors.send(can.Message(arbitration_id=1, data=b"\x00", is_extended_id=False))  # nobody there: lost
        assert motors.unsent == 1
        host = can.Bus(interface="giwbc-unix", channel=channel)
        try:
            host.send(can.Message(arbitration_id=0x42, data=b"hi", is_extended_id=False))
            got = motors.recv(1.0)
            assert motors.connected and got.arbitration_id == 0x42 and bytes(got.data) == b"hi"
        finally:
            host.shutdown()
    finally:
        motors.shutdown()


def test_receive_timeout_is_honoured() -> None:
    host, motors = UnixCanBus.pair()
    try:
        started = time.perf_counter()
        assert host.recv(0.02) is None
        assert 0.015 < time.perf_counter() - started < 0.5
        assert host.recv(0.0) is None
    finally:
        host.shutdown()
        motors.shutdown()


def test_a_full_buffer_and_a_closed_peer_are_clear_errors() -> None:
    host, motors = UnixCanBus.pair()
    frame = can.Message(arbitration_id=1, data=bytes(8), is_extended_id=False)
    sent = 0
    with pytest.raises(can.CanOperationError, match="transmit buffer full"):
        for _ in range(1_000_000):  # nobody reads: the socket buffer fills up
            host.send(frame, timeout=0.0)
            sent += 1
    assert sent > 10
    motors.shutdown()
    with pytest.raises(can.CanOperationError, match="gone|closed"):
        host.send(frame)
    with pytest.raises(can.CanOperationError, match="gone|closed"):
        host.recv(0.1)
    host.shutdown()


def test_no_server_is_a_clear_error() -> None:
    with pytest.raises(can.CanInitializationError, match="no motor side serves"):
        UnixCanBus(f"nobody-{uuid.uuid4().hex[:8]}", connect_timeout=0.05)
    with pytest.raises(ValueError, match="non-empty name"):
        channel_address("")
