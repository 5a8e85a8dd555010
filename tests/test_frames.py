"""Batches of CAN frames and the ports that move them: the struct can_frame layout, the socket and
python-can message ports, full queues, closed peers, CAN FD datagrams, the port group, and the
multi-bus codec (one call for all buses) against each bus's own protocol."""

from __future__ import annotations

import itertools
import socket
import struct
import time

import can
import numpy as np
import pytest

from giwbc.hal.frames import (
    CAN_EFF_FLAG,
    CAN_ERR_FLAG,
    CAN_RTR_FLAG,
    FRAME,
    MessagePort,
    PortGroup,
    SocketPort,
    fields,
    frame_port,
    frames,
    frames_of,
    from_messages,
    to_message,
)
from giwbc.hal.hardware import load_hardware
from giwbc.hal.protocols import CanFrame, MitProtocol
from giwbc.hal.protocols.base import ActuatorProtocol
from giwbc.hal.protocols.multibus import MultiBusCodec
from giwbc.hal.unix_bus import UnixCanBus

_channels = itertools.count()


@pytest.fixture
def pair():
    """Two connected ends of a giwbc-unix channel: (host, motor side)."""
    host, motor = UnixCanBus.pair(f"frames-{next(_channels)}")
    yield host, motor
    host.shutdown()
    motor.shutdown()


def mixed_batch() -> np.ndarray:
    """Standard, extended, remote and error frames of several lengths."""
    batch = frames([0x12, 0x7FF, 0x1ABCDE, 0x05], np.arange(32).reshape(4, 8), [8, 3, 8, 0], [False, False, True, False])
    batch[3]["can_id"] |= CAN_RTR_FLAG
    return np.concatenate([batch, frames_of([CanFrame(0x4, b"\x01\x02")])])


def test_a_record_is_the_kernels_struct_can_frame():
    batch = frames([0x123, 0x1ABCDE], [[1, 2, 3, 4, 5, 6, 7, 8], [9] * 8], [8, 2], [False, True])
    assert FRAME.itemsize == 16
    assert batch.tobytes() == struct.pack("=IB3x8s", 0x123, 8, bytes(range(1, 9))) + struct.pack("=IB3x8s", 0x1ABCDE | CAN_EFF_FLAG, 2, b"\x09" * 8)
    f = fields(batch)
    assert f.arbitration_id.tolist() == [0x123, 0x1ABCDE] and f.extended.tolist() == [False, True]
    assert f.length.tolist() == [8, 2] and not f.remote.any() and not f.error.any()


def test_records_and_python_can_messages_convert_both_ways():
    batch = mixed_batch()
    messages = [to_message(r) for r in batch]
    assert [m.is_extended_id for m in messages] == [False, False, True, False, False]
    assert messages[3].is_remote_frame and bytes(messages[1].data) == bytes([8, 9, 10])
    again = from_messages(messages)
    assert again["can_id"].tolist() == batch["can_id"].tolist() and again["len"].tolist() == batch["len"].tolist()
    for a, b in zip(again, batch):
        n = int(a["len"])
        assert a["data"][:n].tolist() == b["data"][:n].tolist()


def test_the_socket_port_moves_a_batch_exactly(pair):
    host, motor = pair
    tx, rx = frame_port(host), frame_port(motor)
    assert isinstance(tx, SocketPort) and isinstance(rx, SocketPort)
    batch = mixed_batch()
    outcome = tx.send(batch, time.perf_counter() + 1.0)
    assert (outcome.sent, outcome.dropped, outcome.errors) == (len(batch), 0, 0)
    got = rx.receive(time.perf_counter() + 1.0, limit=len(batch))
    assert got.error is None and got.skipped == 0
    assert got.frames.tobytes() == batch.tobytes()
    assert len(rx.receive(None).frames) == 0  # nothing left; returns at once


def test_a_non_classic_datagram_is_skipped_and_counted(pair):
    host, motor = pair
    host.frame_socket.send(bytes(72))  # a struct canfd_frame
    frame_port(host).send(frames([1], np.zeros((1, 8))), time.perf_counter() + 1.0)
    got = frame_port(motor).receive(None)
    assert got.skipped == 1 and len(got.frames) == 1 and got.frames[0]["can_id"] == 1


def test_a_full_queue_drops_frames_by_the_deadline_without_raising(pair):
    host, motor = pair
    host.frame_socket.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    port = frame_port(host)
    batch = frames(np.arange(2000) % 0x7FF, np.zeros((2000, 8)))
    start = time.perf_counter()
    outcome = port.send(batch, start + 0.05, timeout=1e-3, retries=1)
    assert time.perf_counter() - start < 0.5
    assert outcome.sent + outcome.dropped == 2000 and outcome.dropped > 0 and outcome.errors > 0
    assert len(frame_port(motor).receive(None).frames) == outcome.sent  # what was sent arrived, in order


def test_a_closed_peer_is_reported_not_raised(pair):
    host, motor = pair
    motor.shutdown()
    port = frame_port(host)
    outcome = port.send(frames([1, 2], np.zeros((2, 8))), time.perf_counter() + 0.1, retries=2)
    assert outcome.sent == 0 and outcome.dropped == 2 and outcome.errors == 6
    got = port.receive(time.perf_counter() + 0.1)
    assert isinstance(got.error, can.CanOperationError) and len(got.frames) == 0
    host.shutdown()
    outcome = frame_port(host).send(frames([1], np.zeros((1, 8))), time.perf_counter() + 0.1)  # a closed bus
    assert outcome.dropped == 1 and outcome.errors == 1


def test_the_message_port_carries_the_same_frames_on_python_can_virtual():
    channel = f"frames-virtual-{next(_channels)}"
    with can.Bus(interface="virtual", channel=channel) as a, can.Bus(interface="virtual", channel=channel) as b:
        tx, rx = frame_port(a), frame_port(b)
        assert isinstance(tx, MessagePort)
        batch = mixed_batch()
        assert tx.send(batch, time.perf_counter() + 1.0).sent == len(batch)
        got = rx.receive(time.perf_counter() + 1.0, limit=len(batch))
        assert got.frames["can_id"].tolist() == batch["can_id"].tolist()
        for x, y in zip(got.frames, batch):
            n = int(y["len"])
            assert x["len"] == n and x["data"][:n].tolist() == y["data"][:n].tolist()
        start = time.perf_counter()
        assert len(rx.receive(start + 0.05).frames) == 0 and time.perf_counter() - start < 0.5  # silent: returns at the deadline


def test_a_port_group_reads_every_bus_in_bus_order():
    pairs = [UnixCanBus.pair(f"frames-group-{next(_channels)}") for _ in range(3)]
    try:
        hosts = PortGroup([frame_port(h) for h, _ in pairs])
        motors = PortGroup([frame_port(m) for _, m in pairs])
        batch = frames([1, 2, 3, 4, 5], np.arange(40).reshape(5, 8))
        outcomes = hosts.send(batch, [0, 2, 2, 5], time.perf_counter() + 1.0, timeout=[1e-3] * 3, retries=[1] * 3)
        assert [o[0] for o in outcomes] == [2, 0, 3]
        got = motors.receive(None)
        assert got.bus.tolist() == [0, 0, 2, 2, 2] and got.frames.tobytes() == batch.tobytes()
        hosts.send(batch, [0, 2, 2, 5], time.perf_counter() + 1.0, timeout=[1e-3] * 3, retries=[1] * 3)
        some = motors.receive(time.perf_counter() + 1.0, need=[1, 0, 2], buses=[0, 2])
        assert some.bus.tolist() == [0, 2, 2]  # at most need[b] from each, the rest stays queued
        rest = motors.receive(None)
        assert rest.bus.tolist() == [0, 2] and rest.frames["can_id"].tolist() == [2, 5]
    finally:
        for h, m in pairs:
            h.shutdown()
            m.shutdown()


@pytest.fixture(scope="module")
def g1_protocols(g1):
    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    return [b.make_protocol() for b in plan.buses]


class _PerFrameMit(MitProtocol):
    """MIT mode decoded frame by frame (the reference path), and not exactly MitProtocol, so a
    MultiBusCodec over it takes its per-bus path."""

    def decode_frames(self, batch):
        return ActuatorProtocol.decode_frames(self, batch)


def test_the_multibus_codec_equals_each_buses_protocol(g1_protocols, rng):
    fast = MultiBusCodec(g1_protocols)
    reference = MultiBusCodec([_PerFrameMit(p.motors, host_id=p.host_id) for p in g1_protocols])
    n = len(fast.motors)
    values = [rng.uniform(-30, 30, n), rng.uniform(-60, 60, n), rng.uniform(-10, 600, n), rng.uniform(-1, 7, n), rng.uniform(-250, 250, n)]
    a, clamped_a = fast.encode_commands(*values)
    b, clamped_b = reference.encode_commands(*values)
    assert a.tobytes() == b.tobytes() and np.array_equal(clamped_a, clamped_b)
    for kind in ("enter", "exit", "zero"):
        assert fast.special_frames(kind).tobytes() == reference.special_frames(kind).tobytes()
    for _ in range(50):  # replies, garbage, flags, motors with the same id on different buses
        m = 40
        batch = frames(rng.choice([0, 1, 0x7FF], m), rng.integers(0, 256, (m, 8)))
        batch["len"] = rng.choice([0, 3, 6, 7, 8, 8, 8, 12], m)  # 12: a record no classic frame can be (frames() refuses it)
        batch["data"][:, 0] = rng.integers(0, 6, m)
        batch["can_id"][rng.random(m) < 0.1] |= CAN_EFF_FLAG
        batch["can_id"][rng.random(m) < 0.05] |= CAN_ERR_FLAG
        bus = rng.integers(0, len(g1_protocols), m)
        x, y = fast.decode_replies(bus, batch), reference.decode_replies(bus, batch)
        assert x.verdict.tolist() == y.verdict.tolist() and x.index.tolist() == y.index.tolist()
        assert all(x.reply(k) == y.reply(k) for k in range(m))


def test_draining_reads_the_expected_frames_then_any_bus_holding_more():
    pairs = [UnixCanBus.pair(f"frames-drain-{next(_channels)}") for _ in range(3)]
    try:
        hosts = PortGroup([frame_port(h) for h, _ in pairs])
        motors = PortGroup([frame_port(m) for _, m in pairs])
        batch = frames([1, 2, 3, 4, 5, 6], np.arange(48).reshape(6, 8))
        hosts.send(batch, [0, 1, 4, 6], time.perf_counter() + 1.0, timeout=[1e-3] * 3, retries=[1] * 3)  # 1, 3, 2 frames
        got = motors.receive(None, need=[1, 1, 2], drain=True)  # bus 1 holds two more than expected
        assert got.bus.tolist() == [0, 1, 1, 1, 2, 2] and got.frames.tobytes() == batch.tobytes()
        assert len(motors.receive(None).frames) == 0
        hosts.send(batch[:1], [0, 1, 1, 1], time.perf_counter() + 1.0, timeout=[1e-3] * 3, retries=[1] * 3)
        got = motors.receive(None, need=[1, 1, 2], drain=True)  # fewer than expected: what there is
        assert got.bus.tolist() == [0] and all(e is None for e in got.errors)
    finally:
        for h, m in pairs:
            h.shutdown()
            m.shutdown()
