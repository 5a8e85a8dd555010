"""Xsens MTData2 parser and encoder: spec examples, a recorded packet, round trips, split reads,
fuzzed garbage, and the serial IMU source over a pseudo-terminal."""

from __future__ import annotations

import os
import pty
import select
import struct

import numpy as np
import pytest
import serial

from giwbc.hal.xsens import (
    MID_MTDATA2,
    MtSample,
    XbusParser,
    XsensImu,
    checksum,
    decode_mtdata2,
    encode_message,
    encode_mtdata2,
    sample_of_reading,
)
from giwbc.robot.interface import ImuReading

# A recorded MTData2 payload of an MTi-300 (firmware 1.8.2), with its decoded values as MT Manager
# printed them: "Packet Example 6" of docs/mtmanager_packets.md in the public repository
# Scottapotamas/xsens-mti. Items: PacketCounter, SampleTimeFine, Quaternion (ENU), StatusWord.
RECORDED_PAYLOAD = bytes.fromhex(
    "10 20 02 46 82 10 60 04 01 C4 FC 3E 20 10 10 3F 71 CE 6C BE A5 6B CF 3C 61 3B D8 BD 69 1D 25 E0 20 04 00 40 00 03"
)
RECORDED_DECODED = dict(counter=18050, stf=29686846, q_wxyz=(0.94455600, -0.32308814, 0.01374718, -0.05691256), status=0x00400003)


def _sample(k: int, rng: np.random.Generator) -> MtSample:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return MtSample(
        packet_counter=k & 0xFFFF,
        sample_time_fine=(1000 + 25 * k) & 0xFFFFFFFF,
        quaternion=q.astype(np.float32).astype(float),
        acceleration=rng.normal(0, 5, 3).astype(np.float32).astype(float),
        rate_of_turn=rng.normal(0, 2, 3).astype(np.float32).astype(float),
    )


def _same(a: MtSample, b: MtSample) -> None:
    assert a.packet_counter == b.packet_counter and a.sample_time_fine == b.sample_time_fine
    for f in ("quaternion", "acceleration", "rate_of_turn"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))


def test_checksum_matches_the_spec_example_go_to_config() -> None:
    # The spec's GoToConfig message: FA FF 30 00 D1.
    assert encode_message(0x30, b"") == bytes.fromhex("FA FF 30 00 D1")
    assert checksum(bytes.fromhex("FF 30 00")) == 0xD1
    # GoToMeasurement: FA FF 10 00 F1.
    assert encode_message(0x10, b"") == bytes.fromhex("FA FF 10 00 F1")


def test_recorded_mti300_packet_decodes_to_mt_manager_values() -> None:
    msg = encode_message(MID_MTDATA2, RECORDED_PAYLOAD)
    assert sum(msg[1:]) % 256 == 0
    p = XbusParser()
    (s,) = p.feed(msg)
    assert s.packet_counter == RECORDED_DECODED["counter"]
    assert s.sample_time_fine == RECORDED_DECODED["stf"]
    assert s.status_word == RECORDED_DECODED["status"]
    w, x, y, z = RECORDED_DECODED["q_wxyz"]
    np.testing.assert_allclose(s.quaternion, [x, y, z, w], atol=5e-9)
    assert abs(np.linalg.norm(s.quaternion) - 1) < 1e-6
    assert not s.complete  # this configuration has no acceleration or rate of turn
    assert p.counters.checksum_errors == 0 and p.counters.discarded_bytes == 0


def test_spec_derived_message_decodes_exactly() -> None:
    # Built by hand from the spec's layout: item id, size, big-endian float32 values.
    w, x, y, z = 0.5, -0.5, 0.5, 0.5
    payload = (
        struct.pack(">HBH", 0x1020, 2, 7)
        + struct.pack(">HBI", 0x1060, 4, 123456)
        + struct.pack(">HB4f", 0x2010, 16, w, x, y, z)
        + struct.pack(">HB3f", 0x4020, 12, 0.25, -0.5, 9.75)
        + struct.pack(">HB3f", 0x8020, 12, 0.125, 1.5, -2.0)
    )
    body = bytes([0xFF, 0x36, len(payload)]) + payload
    msg = bytes([0xFA]) + body + bytes([(256 - sum(body) % 256) % 256])
    (s,) = XbusParser().feed(msg)
    assert (s.packet_counter, s.sample_time_fine) == (7, 123456)
    np.testing.assert_array_equal(s.quaternion, [x, y, z, w])
    np.testing.assert_array_equal(s.acceleration, [0.25, -0.5, 9.75])
    np.testing.assert_array_equal(s.rate_of_turn, [0.125, 1.5, -2.0])
    assert msg == encode_mtdata2(s)  # the encoder writes the same bytes


def test_extended_length_message_round_trips() -> None:
    filler = b"".join(struct.pack(">HB", 0x0810, 4) + struct.pack(">f", 30.0 + k) for k in range(60))  # temperature items
    s = _sample(3, np.random.default_rng(7))
    msg = encode_mtdata2(s, extra_items=[filler])
    assert msg[3] == 0xFF and struct.unpack(">H", msg[4:6])[0] == len(msg) - 7 >= 255
    (back,) = XbusParser().feed(msg)
    _same(back, s)


def test_float64_items_decode_and_ned_orientation_is_refused() -> None:
    payload = struct.pack(">HB4d", 0x2013, 32, 1.0, 0.0, 0.0, 0.0) + struct.pack(">HB3d", 0x8023, 24, 0.1, 0.2, 0.3)
    p = XbusParser()
    (s,) = p.feed(encode_message(MID_MTDATA2, payload))
    np.testing.assert_array_equal(s.quaternion, [0, 0, 0, 1])
    np.testing.assert_array_equal(s.rate_of_turn, [0.1, 0.2, 0.3])
    ned = struct.pack(">HB4f", 0x2014, 16, 1.0, 0.0, 0.0, 0.0)  # quaternion, NED
    (s,) = p.feed(encode_message(MID_MTDATA2, ned))
    assert s.quaternion is None and p.counters.unsupported_items == 1


def test_round_trip_of_many_samples_in_one_and_in_split_reads() -> None:
    rng = np.random.default_rng(11)
    samples = [_sample(k, rng) for k in range(50)]
    stream = b"".join(encode_mtdata2(s) for s in samples)
    got = XbusParser().feed(stream)
    assert len(got) == 50
    for a, b in zip(got, samples):
        _same(a, b)
    for chunk in (1, 2, 3, 7, 13, 64):
        p = XbusParser()
        got = [s for k in range(0, len(stream), chunk) for s in p.feed(stream[k : k + chunk])]
        assert len(got) == 50 and p.pending == 0
        _same(got[-1], samples[-1])


def test_fuzzed_garbage_never_crashes_and_the_parser_resynchronises() -> None:
    rng = np.random.default_rng(20240)
    samples = [_sample(k, rng) for k in range(40)]
    p = XbusParser()
    got: list[MtSample] = []
    stream = bytearray()
    for s in samples:
        junk = rng.integers(0, 256, size=int(rng.integers(0, 60)), dtype=np.uint8).tobytes()
        if rng.random() < 0.3:
            junk += b"\xfa\xff\x36"  # a false start right before a real message
        stream += junk + encode_mtdata2(s)
    # a false start with a large length byte waits for that many bytes before its checksum fails:
    # a live stream goes on, so the last real message is followed by more
    tail = [_sample(100 + k, rng) for k in range(20)]
    stream += b"".join(encode_mtdata2(t) for t in tail)
    for k in range(0, len(stream), 17):
        got += p.feed(bytes(stream[k : k + 17]))
    # every real sample is recovered, in order, and nothing else (a false start swallows none: it
    # is dropped by its first byte when its checksum or length fails)
    assert [s.packet_counter for s in got] == [s.packet_counter for s in samples + tail]
    for a, b in zip(got, samples):
        _same(a, b)
    assert p.counters.checksum_errors > 0
    assert p.counters.discarded_bytes > 0
    # pure noise: no crash, bounded memory, noise counted
    p2 = XbusParser()
    for _ in range(200):
        p2.feed(rng.integers(0, 256, size=int(rng.integers(1, 400)), dtype=np.uint8).tobytes())
    assert p2.pending <= 2048 + 7
    assert p2.counters.discarded_bytes > 0.9 * p2.counters.bytes_in - 2048 - 7
    # and it still decodes a good message afterwards
    (s,) = [x for x in p2.feed(b"\x00" * 2100 + encode_mtdata2(samples[0])) if x.complete and x.packet_counter == 0]
    _same(s, samples[0])


def test_corrupted_byte_is_a_checksum_error_and_the_next_message_still_decodes() -> None:
    rng = np.random.default_rng(5)
    a, b = _sample(1, rng), _sample(2, rng)
    bad = bytearray(encode_mtdata2(a))
    bad[20] ^= 0x40
    p = XbusParser()
    got = p.feed(bytes(bad) + encode_mtdata2(b))
    assert [s.packet_counter for s in got] == [2]
    assert p.counters.checksum_errors == 1


def test_truncated_item_is_malformed_not_a_crash() -> None:
    payload = struct.pack(">HB", 0x2010, 16) + b"\x00" * 8  # says 16 bytes, holds 8
    p = XbusParser()
    assert p.feed(encode_message(MID_MTDATA2, payload)) == []
    assert p.counters.malformed == 1
    assert decode_mtdata2(b"\x20") is None


def test_serial_imu_reads_through_a_pseudo_terminal() -> None:
    master, slave = pty.openpty()
    port = serial.Serial(os.ttyname(slave), baudrate=921600, timeout=0)
    imu = XsensImu(port)
    try:
        assert imu.read() is None
        truth = ImuReading(np.array([0.0, 0.0, np.sin(0.2), np.cos(0.2)]), np.array([0.1, -0.2, 0.3]), np.array([0.0, 0.5, 9.81]), 12.3456)
        os.write(master, encode_mtdata2(sample_of_reading(truth, 9)))
        for _ in range(200):  # the pty delivers the bytes when the kernel gets to it (a loaded machine: later)
            select.select([port.fileno()], [], [], 0.05)
            r = imu.read()
            if r is not None:
                break
        assert r is not None
        np.testing.assert_allclose(r.quaternion, truth.quaternion, atol=1e-7)
        np.testing.assert_allclose(r.angular_velocity, truth.angular_velocity, atol=1e-7)
        np.testing.assert_allclose(r.linear_acceleration, truth.linear_acceleration, atol=1e-6)
        assert r.time == pytest.approx(12.3456, abs=1e-9)
        assert imu.read() is r  # nothing new: the same sample (the estimator sees it as stale)
        os.write(master, b"\xfa\xff\x36\x05garbage")
        imu.read()
        assert imu.counters["samples"] == 1
    finally:
        imu.close()
        os.close(master)
        os.close(slave)


class _Bytes:
    def __init__(self) -> None:
        self.buf = bytearray()

    @property
    def in_waiting(self) -> int:
        return len(self.buf)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self.buf[:size])
        del self.buf[:size]
        return out

    def close(self) -> None:
        pass


def test_sample_time_fine_wraps_into_a_monotonic_time() -> None:
    port = _Bytes()
    imu = XsensImu(port)
    rng = np.random.default_rng(3)
    times = []
    for k, ticks in enumerate((2**32 - 20, 2**32 - 1, 5, 25)):
        s = _sample(k, rng)
        port.buf += encode_mtdata2(MtSample(k, ticks, s.quaternion, s.acceleration, s.rate_of_turn))
        times.append(imu.read().time)
    assert np.all(np.diff(times) > 0)
    assert times[2] - times[1] == pytest.approx(6e-4)


def test_incomplete_samples_are_counted_not_published() -> None:
    port = _Bytes()
    imu = XsensImu(port)
    port.buf += encode_message(MID_MTDATA2, RECORDED_PAYLOAD)
    assert imu.read() is None and imu.counters["incomplete"] == 1
