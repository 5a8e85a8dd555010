"""giwbc-unix against python-can's back-to-back interface scenarios (two ends of one channel), as
python-can's own interface tests run them, plus CAN FD: refused with a clear error everywhere on
the host's frame paths (the interface and the batched path), never cut to 8 bytes."""

from __future__ import annotations

import itertools
import select
import socket
import struct
import time
import uuid
from concurrent.futures import ThreadPoolExecutor

import can
import numpy as np
import pytest

from giwbc.hal.frames import FRAME, MessagePort, frame_port, frames, frames_of, to_message
from giwbc.hal.protocols import CanFrame
from giwbc.hal.unix_bus import UnixCanBus

TIMEOUT = 0.5  # s: how long a receive may wait for a frame that was sent (an upper bound, never reached when all is well)
_ids = itertools.count()


def channel() -> str:
    return f"b2b-{uuid.uuid4().hex[:8]}-{next(_ids)}"


@pytest.fixture(params=[can.Bus, can.ThreadSafeBus], ids=["Bus", "ThreadSafeBus"])
def ends(request):
    """Two ends of one giwbc-unix channel, opened through python-can by name: (bus1, bus2)."""
    name = channel()
    motor_side = request.param(interface="giwbc-unix", channel=name, serve=True)
    host = request.param(interface="giwbc-unix", channel=name)
    assert motor_side.recv(0.05) is None  # accepts the host
    yield motor_side, host
    host.shutdown()
    motor_side.shutdown()


def same(received: can.Message | None, sent: can.Message) -> None:
    """python-can's check of a received message against the sent one."""
    assert received is not None
    assert received.arbitration_id == sent.arbitration_id
    assert received.is_extended_id == sent.is_extended_id
    assert received.is_remote_frame == sent.is_remote_frame
    assert received.is_error_frame == sent.is_error_frame
    assert received.is_fd == sent.is_fd
    assert received.bitrate_switch == sent.bitrate_switch
    assert received.dlc == sent.dlc
    if not sent.is_remote_frame:
        assert bytes(received.data) == bytes(sent.data)


def send_and_receive(bus1: can.BusABC, bus2: can.BusABC, msg: can.Message) -> None:
    """Send on bus 1, receive on bus 2, and back with the next id (python-can's ``_send_and_receive``)."""
    bus1.send(msg)
    same(bus2.recv(TIMEOUT), msg)
    assert bus1.recv(0) is None  # a two-node channel: an end never receives its own frames
    msg.arbitration_id += 1
    bus2.send(msg)
    same(bus1.recv(TIMEOUT), msg)


def test_no_message(ends):
    assert ends[0].recv(0.05) is None and ends[1].recv(0) is None


def test_standard_message(ends):
    send_and_receive(*ends, can.Message(is_extended_id=False, arbitration_id=0x100, data=[1, 2, 3, 4, 5, 6, 7, 8]))


def test_extended_message(ends):
    send_and_receive(*ends, can.Message(is_extended_id=True, arbitration_id=0x123456, data=[10, 11, 12, 13, 14, 15, 16, 17]))


def test_remote_message(ends):
    """A remote frame asks for 4 bytes: it arrives with dlc 4 and no data."""
    send_and_receive(*ends, can.Message(is_extended_id=False, arbitration_id=0x200, is_remote_frame=True, dlc=4))
    ends[0].send(can.Message(is_extended_id=False, arbitration_id=0x200, is_remote_frame=True, dlc=4))
    got = ends[1].recv(TIMEOUT)
    assert got.dlc == 4 and len(got.data) == 0


def test_dlc_less_than_eight(ends):
    send_and_receive(*ends, can.Message(is_extended_id=False, arbitration_id=0x300, data=[4, 5, 6]))
    send_and_receive(*ends, can.Message(is_extended_id=False, arbitration_id=0x301, data=[]))


def test_timestamps_are_absolute_ordered_and_sub_second(ends):
    """Each timestamp lies between the wall clock read before sending and after receiving, a later
    frame's is later by at least the pause between them, and they resolve below a second."""
    bus1, bus2 = ends
    before = time.time()
    bus2.send(can.Message())
    first = bus1.recv(TIMEOUT)
    time.sleep(0.02)
    bus2.send(can.Message())
    second = bus1.recv(TIMEOUT)
    after = time.time()
    assert before <= first.timestamp <= second.timestamp <= after
    assert second.timestamp - first.timestamp >= 0.02
    assert first.timestamp % 1 + second.timestamp % 1 > 0 and first.timestamp != second.timestamp


def test_fileno_is_a_descriptor_that_becomes_readable(ends):
    bus1, bus2 = ends
    fd = bus1.fileno()
    assert isinstance(fd, int) and fd > 0
    assert not select.select([fd], [], [], 0)[0]
    bus2.send(can.Message(arbitration_id=1, is_extended_id=False, data=b"\x01"))
    assert select.select([fd], [], [], TIMEOUT)[0] == [fd]
    assert bus1.recv(0).arbitration_id == 1


def test_filters(ends):
    """python-can's software filters apply (the interface filters nothing itself)."""
    bus1, bus2 = ends
    bus2.set_filters([{"can_id": 0x123, "can_mask": 0x7FF, "extended": False}])
    for arbitration_id, extended in ((0x124, False), (0x123, True), (0x123, False), (0x523, False)):
        bus1.send(can.Message(arbitration_id=arbitration_id, is_extended_id=extended, data=b"\x00"))
    got = bus2.recv(TIMEOUT)
    assert (got.arbitration_id, got.is_extended_id) == (0x123, False)
    assert bus2.recv(0.05) is None
    bus2.set_filters(None)
    bus1.send(can.Message(arbitration_id=0x124, is_extended_id=False))
    assert bus2.recv(TIMEOUT).arbitration_id == 0x124


def test_send_periodic_stops_after_its_duration(ends):
    """A periodic send transmits for its duration only: at most duration / period + 1 frames, then
    nothing more arrives."""
    bus1, bus2 = ends
    for duration, period in ((0.01, 0.003), (0.1, 0.011)):
        task = bus2.send_periodic(can.Message(arbitration_id=0x77, is_extended_id=False), period, duration)
        messages = []
        while (msg := bus1.recv(max(0.1, period * 5))) is not None:
            messages.append(msg)
        assert 1 <= len(messages) <= int(duration / period) + 1
        assert all(m.arbitration_id == 0x77 for m in messages)
        task.stop()
        assert bus1.recv(0.05) is None


def test_double_shutdown():
    name = channel()
    motor_side = can.Bus(interface="giwbc-unix", channel=name, serve=True)
    host = can.Bus(interface="giwbc-unix", channel=name)
    host.shutdown()
    host.shutdown()
    motor_side.shutdown()
    motor_side.shutdown()
    with pytest.raises(can.CanOperationError, match="closed"):
        host.send(can.Message())


def test_thread_safe_bus_with_1000_concurrent_sends():
    """python-can's concurrent-writes scenario: 1,000 sends from 100 threads, 1,000 receives from
    100 threads on ``ThreadSafeBus`` ends; every frame arrives whole."""
    name = channel()
    bus2 = can.ThreadSafeBus(interface="giwbc-unix", channel=name, serve=True)
    bus1 = can.ThreadSafeBus(interface="giwbc-unix", channel=name)
    message = can.Message(arbitration_id=0x123, is_extended_id=True, timestamp=121334.365, data=[254, 255, 1, 2])
    try:
        assert bus2.recv(0.05) is None
        with ThreadPoolExecutor(100) as senders, ThreadPoolExecutor(100) as receivers:
            sent = [senders.submit(bus1.send, message) for _ in range(1000)]
            received = list(receivers.map(lambda _: bus2.recv(5.0), range(1000)))
            for f in sent:
                f.result()
        assert all(m is not None and message.equals(m, timestamp_delta=None) for m in received)
        assert bus2.recv(0.05) is None
    finally:
        bus1.shutdown()
        bus2.shutdown()


# ----------------------------------------------------------------------------- CAN FD
def test_can_fd_is_refused_at_construction_and_at_send_never_cut(ends):
    """The issue's case: a 64-byte FD frame used to arrive as 8 bytes. It is refused at send with
    a clear error, nothing reaches the other end; an end cannot be opened with fd=True."""
    bus1, bus2 = ends
    for msg in (
        can.Message(is_fd=True, is_extended_id=True, arbitration_id=0x56789, data=[0xFF] * 64),
        can.Message(is_fd=True, bitrate_switch=True, is_extended_id=True, arbitration_id=0x98765, data=[0xFF] * 48),
        can.Message(is_fd=True, is_extended_id=False, arbitration_id=0x12, data=[1, 2]),  # FD even when short
        can.Message(arbitration_id=0x12, is_extended_id=False, data=[0xAA] * 12, check=False),  # not FD, over 8 bytes
    ):
        with pytest.raises(can.CanOperationError, match="CAN FD|over 8 bytes"):
            bus2.send(msg)
    assert bus1.recv(0.05) is None
    with pytest.raises(can.CanInitializationError, match="CAN FD is not supported"):
        can.Bus(interface="giwbc-unix", channel=channel(), serve=True, fd=True)


def test_a_non_classic_datagram_is_an_error_not_a_shorter_frame():
    """A peer that writes a 72-byte canfd_frame (or a classic frame claiming 12 bytes) gets an error
    on the receiving end, never an 8-byte prefix."""
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    bus = UnixCanBus("raw", _socket=a)
    try:
        b.send(struct.pack("=IBBBB64s", 0x56789 | 0x80000000, 64, 0x01, 0, 0, b"\xff" * 64))
        with pytest.raises(can.CanOperationError, match="72-byte datagram is not a classic CAN frame"):
            bus.recv(TIMEOUT)
        b.send(struct.pack("=IB3x8s", 0x12, 12, b"\xaa" * 8))
        with pytest.raises(can.CanOperationError, match="12 data bytes"):
            bus.recv(TIMEOUT)
        b.send(struct.pack("=IB3x8s", 0x12, 2, b"\xaa" * 8))
        got = bus.recv(TIMEOUT)
        assert bytes(got.data) == b"\xaa\xaa" and got.dlc == 2
    finally:
        bus.shutdown()
        b.close()


def test_the_batched_path_refuses_can_fd_too():
    """Batches are struct can_frame records: an FD bus is refused when its port is made, a batch
    cannot say more than 8 bytes, a record claiming more is never sent cut, and an FD frame that
    reaches a classic port is skipped and counted."""
    fd_bus = can.Bus(interface="virtual", channel=channel(), protocol=can.CanProtocol.CAN_FD)
    try:
        with pytest.raises(can.CanInitializationError, match="classic CAN frames only"):
            frame_port(fd_bus)
    finally:
        fd_bus.shutdown()
    with pytest.raises(ValueError, match="0..8 data bytes"):
        frames([1], np.zeros((1, 8)), lengths=[12])
    with pytest.raises(ValueError, match="at most 8"):
        frames_of([CanFrame(1, bytes(12))])
    record = np.zeros(1, dtype=FRAME)
    record["len"] = 12
    with pytest.raises(ValueError, match="12 data bytes"):
        to_message(record[0])
    name = channel()
    host, other = can.Bus(interface="virtual", channel=name), can.Bus(interface="virtual", channel=name)
    try:
        port = frame_port(host)
        assert isinstance(port, MessagePort)
        with pytest.raises(ValueError, match="more than 8"):
            port.send(record, time.perf_counter() + 1.0)
        assert other.recv(0.05) is None
        other.send(can.Message(is_fd=True, arbitration_id=5, is_extended_id=False, data=[1] * 16))
        other.send(can.Message(arbitration_id=6, is_extended_id=False, data=[2] * 8))
        got = port.receive(time.perf_counter() + TIMEOUT, limit=1)
        assert got.skipped == 1 and got.frames["can_id"].tolist() == [6]
    finally:
        host.shutdown()
        other.shutdown()
