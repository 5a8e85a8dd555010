"""The configurable CAN IMU: layout validation, exact decoding of hand-built frames, round trips
through the encoder, lost and short frames, fuzzed frames, and the IMU's share of the bus load."""

from __future__ import annotations

import math
import struct
import tomllib

import numpy as np
import pytest

from giwbc.errors import HardwareConfigError
from giwbc.hal.can_imu import CanImu, CanImuEncoder, parse_can_imu_layout
from giwbc.hal.frames import CAN_EFF_FLAG, FRAME, frames
from giwbc.hal.hardware import parse_hardware
from giwbc.robot.interface import ImuReading
from giwbc.robot.so3 import quat_to_rpy, rpy_to_quat

Q15 = 1.0 / 32768.0
GYRO_LSB = math.radians(2000.0) / 32768.0  # +-2000 deg/s full scale
ACC_LSB = 16 * 9.80665 / 32768.0  # +-16 g full scale

# A quaternion IMU in three frames: quaternion (Q15), rate of turn + a 1 ms tick counter, acceleration.
QUAT_LAYOUT = f"""
source = "can"
bus = "imu"
rate = 500.0
[[frames]]
id = 0x50
fields = [{{ name = "qw", byte = 0, type = "i16", scale = {Q15!r} }}, {{ name = "qx", byte = 2, type = "i16", scale = {Q15!r} }},
          {{ name = "qy", byte = 4, type = "i16", scale = {Q15!r} }}, {{ name = "qz", byte = 6, type = "i16", scale = {Q15!r} }}]
[[frames]]
id = 0x51
fields = [{{ name = "gx", byte = 0, type = "i16", scale = {GYRO_LSB!r} }}, {{ name = "gy", byte = 2, type = "i16", scale = {GYRO_LSB!r} }},
          {{ name = "gz", byte = 4, type = "i16", scale = {GYRO_LSB!r} }}, {{ name = "time", byte = 6, type = "u16", scale = 0.001 }}]
[[frames]]
id = 0x52
fields = [{{ name = "ax", byte = 0, type = "i16", scale = {ACC_LSB!r} }}, {{ name = "ay", byte = 2, type = "i16", scale = {ACC_LSB!r} }},
          {{ name = "az", byte = 4, type = "i16", scale = {ACC_LSB!r} }}]
"""

# Euler angles (0.01 deg), big-endian, floats for rates and acceleration, 29-bit ids.
EULER_LAYOUT = """
source = "can"
bus = "imu"
rate = 1000.0
[[frames]]
id = 0x18FF0101
extended = true
endian = "big"
fields = [{ name = "roll", byte = 0, type = "i16", scale = 1.7453292519943296e-04 },
          { name = "pitch", byte = 2, type = "i16", scale = 1.7453292519943296e-04 },
          { name = "yaw", byte = 4, type = "u16", scale = 1.7453292519943296e-04, bias = -3.141592653589793 }]
[[frames]]
id = 0x18FF0102
extended = true
endian = "big"
fields = [{ name = "gx", byte = 0, type = "f32" }, { name = "gy", byte = 4, type = "f32" }]
[[frames]]
id = 0x18FF0103
extended = true
fields = [{ name = "gz", byte = 0, type = "f32" }, { name = "az", byte = 4, type = "f32", endian = "big" }]
[[frames]]
id = 0x18FF0104
extended = true
fields = [{ name = "ax", byte = 0, type = "f32" }, { name = "ay", byte = 4, type = "f32" }]
"""


def layout(text: str):
    return parse_can_imu_layout(tomllib.loads(text))


def batch(ids, payloads) -> np.ndarray:
    data = np.zeros((len(ids), 8), dtype=np.uint8)
    for k, p in enumerate(payloads):
        data[k, : len(p)] = np.frombuffer(p, dtype=np.uint8)
    return frames(ids, data, [len(p) for p in payloads])


def test_hand_built_frames_decode_exactly() -> None:
    imu = CanImu(layout(QUAT_LAYOUT))
    q_raw = (23170, 0, 0, 23170)  # w, x, y, z: 90 deg about z
    g_raw, a_raw = (100, -200, 300), (0, 0, 2048)  # 2048 counts = 1 g
    b = batch(
        [0x50, 0x51, 0x52],
        [struct.pack("<4h", *q_raw), struct.pack("<3hH", *g_raw, 1234), struct.pack("<3h", *a_raw)],
    )
    mask = imu.take(b, now=99.0)
    assert mask.tolist() == [True, True, True]
    r = imu.read()
    np.testing.assert_allclose(r.quaternion, [0, 0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(r.angular_velocity, np.array(g_raw) * GYRO_LSB, rtol=0, atol=1e-15)
    np.testing.assert_allclose(r.linear_acceleration, [0, 0, 9.80665], atol=1e-12)
    assert r.time == pytest.approx(1.234)  # device time, not the host's 99.0
    assert imu.counters.samples == 1


def test_euler_big_endian_extended_floats_decode_exactly() -> None:
    lay = layout(EULER_LAYOUT)
    imu = CanImu(lay)
    roll, pitch, yaw = 1000, -500, 18000 + 9000  # 10 deg, -5 deg, +90 deg (bias -180 deg)
    payloads = [
        struct.pack(">hhH", roll, pitch, yaw),
        struct.pack(">ff", 0.5, -0.25),
        struct.pack("<f", 0.125) + struct.pack(">f", 9.75),
        struct.pack("<ff", 0.0, -1.5),
    ]
    ids = [i | CAN_EFF_FLAG for i in (0x18FF0101, 0x18FF0102, 0x18FF0103, 0x18FF0104)]
    assert imu.take(batch(ids, payloads), now=5.0).all()
    r = imu.read()
    np.testing.assert_allclose(quat_to_rpy(r.quaternion), np.radians([10.0, -5.0, 90.0]), atol=1e-12)
    np.testing.assert_array_equal(r.angular_velocity, [0.5, -0.25, 0.125])
    np.testing.assert_array_equal(r.linear_acceleration, [0.0, -1.5, 9.75])
    assert r.time == 5.0  # no time field: host time
    # a standard frame with the same low bits is not the IMU's
    assert not imu.take(batch([0x18FF0101 & 0x7FF], [payloads[0]])).any()


@pytest.mark.parametrize("text", [QUAT_LAYOUT, EULER_LAYOUT])
def test_encoder_round_trip(text: str) -> None:
    lay = layout(text)
    enc, imu = CanImuEncoder(lay), CanImu(lay)
    rng = np.random.default_rng(42)
    for k in range(200):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        truth = ImuReading(q, rng.uniform(-5, 5, 3), rng.uniform(-50, 50, 3), 0.002 * k)
        assert imu.take(enc.encode(truth), now=0.002 * k).all()
        r = imu.read()
        same = np.allclose(r.quaternion, q, atol=2e-4) or np.allclose(r.quaternion, -q, atol=2e-4)
        assert same, (r.quaternion, q)
        tol_g = GYRO_LSB if "0x50" in text else 1e-6
        np.testing.assert_allclose(r.angular_velocity, truth.angular_velocity, atol=tol_g)
        np.testing.assert_allclose(r.linear_acceleration, truth.linear_acceleration, atol=ACC_LSB if "0x50" in text else 1e-5)
    assert imu.counters.samples == 200 and enc.clamped == 0


def test_tick_counter_wraps_into_monotonic_time() -> None:
    lay = layout(QUAT_LAYOUT)
    enc, imu = CanImuEncoder(lay), CanImu(lay)
    times = []
    for t in (65.530, 65.534, 65.538, 65.542):  # the u16 ms counter wraps at 65.536 s
        imu.take(enc.encode(ImuReading(np.array([0, 0, 0, 1.0]), np.zeros(3), np.array([0, 0, 9.81]), t)))
        times.append(imu.read().time)
    np.testing.assert_allclose(np.diff(times), 0.004, atol=1e-9)


def test_lost_and_short_frames_are_counted_and_never_mix_samples() -> None:
    lay = layout(QUAT_LAYOUT)
    enc, imu = CanImuEncoder(lay), CanImu(lay)
    a = enc.encode(ImuReading(np.array([0, 0, 0, 1.0]), np.ones(3), np.array([0, 0, 9.81]), 1.0))
    b = enc.encode(ImuReading(np.array([1.0, 0, 0, 0]), -np.ones(3), np.array([0, 0, -9.81]), 2.0))
    imu.take(a[:2])  # the acceleration frame of sample a is lost
    assert imu.read() is None
    imu.take(b)  # b's quaternion frame repeats an id: a's partial sample is dropped
    assert imu.counters.incomplete == 1
    r = imu.read()
    assert r.time == pytest.approx(2.0) and r.linear_acceleration[2] < 0 and r.angular_velocity[0] < 0
    short = a[2:].copy()
    short["len"] = 5
    imu.take(short)
    assert imu.counters.short_frames == 1 and imu.read() is r


def test_fuzzed_frames_never_crash() -> None:
    lay = layout(QUAT_LAYOUT)
    imu = CanImu(lay)
    rng = np.random.default_rng(77)
    ours = 0
    for _ in range(300):
        n = int(rng.integers(1, 20))
        b = np.zeros(n, dtype=FRAME)
        b["can_id"] = rng.choice([0x50, 0x51, 0x52, 0x01, 0x7FF, 0x50 | CAN_EFF_FLAG], size=n)
        b["len"] = rng.integers(0, 9, size=n)
        b["data"] = rng.integers(0, 256, size=(n, 8))
        mask = imu.take(b)
        expect = np.isin(b["can_id"], [0x50, 0x51, 0x52])
        np.testing.assert_array_equal(mask, expect)
        ours += int(expect.sum())
    c = imu.counters
    assert c.frames == ours and c.samples > 0 and c.short_frames > 0 and c.incomplete > 0
    r = imu.read()
    assert r is not None and abs(np.linalg.norm(r.quaternion) - 1) < 1e-12


@pytest.mark.parametrize(
    "change, match",
    [
        (("rate = 500.0", "rate = 0.0"), "rate must be > 0"),
        (('name = "qz"', 'name = "qq"'), "name must be one of"),
        (('name = "qz"', 'name = "qy"'), "'qy' already comes from"),
        (('byte = 6, type = "i16", scale', 'byte = 5, type = "i16", scale'), "overlaps"),
        (('{ name = "az", byte = 4', '{ name = "az", byte = 7'), "past the 8 bytes"),
        (('type = "u16"', 'type = "u64"'), "type must be one of"),
        (("id = 0x52", "id = 0x51"), "duplicate frame id"),
        (("id = 0x52", "id = 0x800"), "id must be an integer in 0..0x7FF"),
        (('{ name = "az", byte = 4', '{ name = "time2", byte = 4'), "name must be one of"),
    ],
)
def test_layout_errors_name_the_problem(change, match) -> None:
    text = QUAT_LAYOUT.replace(*change, 1)
    assert text != QUAT_LAYOUT, change
    with pytest.raises(HardwareConfigError, match=match):
        layout(text)


def test_layout_needs_a_full_orientation_rate_and_acceleration() -> None:
    no_qz = QUAT_LAYOUT.replace(', {{ name = "qz", byte = 6, type = "i16", scale = {q} }}]'.format(q=repr(Q15)), "]")
    assert no_qz != QUAT_LAYOUT
    with pytest.raises(HardwareConfigError, match="orientation needs all of"):
        layout(no_qz)
    with pytest.raises(HardwareConfigError, match="missing"):
        layout(QUAT_LAYOUT.split("[[frames]]\nid = 0x52")[0])


BUS_TOML = """
[[buses]]
name = "imu"
interface = "socketcan"
channel = "can4"
bitrate = 1000000
host_id = 0
"""


def _motors(n: int) -> str:
    return "".join(f'\n[[motors]]\nbus = "imu"\nid = {k + 1}\njoint = "j{k}"\nmodel = "DM8009"\n' for k in range(n))


def test_imu_frames_count_in_the_bus_capacity_check() -> None:
    imu = "\n[imu]\n" + QUAT_LAYOUT.replace("[[frames]]", "[[imu.frames]]")
    without = parse_hardware(BUS_TOML + _motors(2) + '\n[imu]\nsource = "emulated"\n', 1000.0)
    with_imu = parse_hardware(BUS_TOML + _motors(2) + imu, 1000.0)
    added = with_imu.loads["imu"].bits_nominal - without.loads["imu"].bits_nominal
    assert added == 3 * 111  # three 8-byte standard frames per 1 ms cycle (rounded up from 0.5)
    # at 250 Hz control the 500 Hz IMU sends two frames of each id per cycle
    assert parse_hardware(BUS_TOML + _motors(2) + imu, 250.0).loads["imu"].bits_nominal == 2 * 222 + 6 * 111
    # 3 motors fit a 1 Mbit/s bus at 1 kHz (66.6 %), with the IMU they do not (99.9 %)
    parse_hardware(BUS_TOML + _motors(3) + '\n[imu]\nsource = "emulated"\n', 1000.0)
    with pytest.raises(HardwareConfigError, match="over capacity"):
        parse_hardware(BUS_TOML + _motors(3) + imu, 1000.0)
    # an IMU frame id that is a motor's id or the motors' reply id is refused
    with pytest.raises(HardwareConfigError, match="host_id"):
        parse_hardware(BUS_TOML + _motors(1) + imu.replace("id = 0x50", "id = 0"), 500.0)


def test_rpy_quaternion_conversions_invert() -> None:
    rng = np.random.default_rng(9)
    for _ in range(100):
        rpy = rng.uniform([-3, -1.5, -3], [3, 1.5, 3])
        q = rpy_to_quat(*rpy)
        assert abs(np.linalg.norm(q) - 1) < 1e-12
        np.testing.assert_allclose(quat_to_rpy(q), rpy, atol=1e-9)
    # R = Rz(yaw) Ry(pitch) Rx(roll): yaw alone is a rotation about z
    np.testing.assert_allclose(rpy_to_quat(0, 0, math.pi / 2), [0, 0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-15)
