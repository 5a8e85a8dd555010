"""Wire compatibility of giwbc's unitree_hg messages: what giwbc serialises is, byte for byte, the
message built by hand from Unitree's public IDL (XCDR1 field order, alignment and array sizes) with
Unitree's CRC over the C struct; a message with a bad CRC is refused."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from giwbc.hal.dds.crc import crc32_reference, unitree_crc
from giwbc.hal.dds.messages import BAD_CRC, BAD_SIZE, OK, LowCmd, LowState

N = 35
HEADER = b"\x00\x01\x00\x00"  # XCDR1 little endian


def _f32(values: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(values, dtype=np.float32)]


def _crc_of_c_struct(c_bytes: bytes) -> int:
    words = struct.unpack(f"<{len(c_bytes) // 4 - 1}I", c_bytes[:-4])
    return crc32_reference(list(words))


def _random_cmd(rng: np.random.Generator) -> dict:
    return {
        "mode_pr": int(rng.integers(0, 2)), "mode_machine": int(rng.integers(0, 256)), "mode": rng.integers(0, 2, N),
        "f": rng.normal(size=(N, 5)).astype(np.float32), "reserve": rng.integers(0, 2**32, N), "tail": rng.integers(0, 2**32, 4),
    }  # fmt: skip


def _cmd_by_hand(m: dict) -> tuple[bytes, bytes]:
    """(wire bytes, C struct) of a LowCmd_ from the IDL, field by field."""
    wire, c = struct.pack("<BB", m["mode_pr"], m["mode_machine"]), struct.pack("<BBxx", m["mode_pr"], m["mode_machine"])
    for i in range(N):
        record = struct.pack("<5fI", *_f32(m["f"][i]), int(m["reserve"][i]))
        wire += struct.pack("<B", int(m["mode"][i]))
        wire += b"\x00" * (-len(wire) % 4) + record  # CDR: each float aligned to 4 from the payload's start
        c += struct.pack("<Bxxx", int(m["mode"][i])) + record
    tail = struct.pack("<4I", *map(int, m["tail"]))
    c += tail + b"\x00" * 4
    crc = _crc_of_c_struct(c)
    return HEADER + wire + tail + struct.pack("<I", crc), c[:-4] + struct.pack("<I", crc)


def _fill_cmd(msg: LowCmd, m: dict) -> None:
    msg.field("mode_pr")[0], msg.field("mode_machine")[0] = m["mode_pr"], m["mode_machine"]
    msg.set_modes(m["mode"])
    msg.floats[:] = m["f"]
    msg.reserve[:] = m["reserve"]
    msg.field("reserve")[:] = m["tail"]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lowcmd_bytes_match_the_idl_built_by_hand(seed: int) -> None:
    m = _random_cmd(np.random.default_rng(seed))
    wire, c = _cmd_by_hand(m)
    msg = LowCmd()
    _fill_cmd(msg, m)
    sealed = msg.seal()
    assert len(sealed) == len(wire) == 1004
    assert sealed == wire
    assert msg.c_struct().tobytes()[:-4] == c[:-4]
    assert unitree_crc(c) == struct.unpack("<I", wire[-4:])[0]


def test_lowcmd_matches_cyclone_serialisation_of_the_idl_types() -> None:
    pytest.importorskip("cyclonedds")
    from giwbc.hal.dds.idl import LowCmd_, MotorCmd_

    m = _random_cmd(np.random.default_rng(5))
    msg = LowCmd()
    _fill_cmd(msg, m)
    sealed = msg.seal()
    ref = LowCmd_(m["mode_pr"], m["mode_machine"],
                  [MotorCmd_(int(m["mode"][i]), *_f32(m["f"][i]), int(m["reserve"][i])) for i in range(N)],
                  [int(v) for v in m["tail"]], int(msg.crc_word[0]))  # fmt: skip
    assert ref.serialize() == sealed
    back = LowCmd_.deserialize(sealed)
    assert back.motor_cmd[7].kp == pytest.approx(float(m["f"][7, 3]))


def _state_by_hand(rng: np.random.Generator) -> tuple[bytes, dict]:
    v = {
        "version": rng.integers(0, 2**32, 2), "mode_pr": 1, "mode_machine": 5, "tick": int(rng.integers(0, 2**32)),
        "imu": rng.normal(size=13).astype(np.float32), "imu_temp": int(rng.integers(-100, 100)), "mode": rng.integers(0, 2, N),
        "f": rng.normal(size=(N, 4)).astype(np.float32), "temp": rng.integers(-40, 120, (N, 2)), "vol": rng.normal(size=N),
        "sensor": rng.integers(0, 2**32, (N, 2)), "motorstate": rng.integers(0, 2**32, N), "reserve": rng.integers(0, 2**32, (N, 4)),
        "remote": rng.integers(0, 256, 40), "tail": rng.integers(0, 2**32, 4),
    }  # fmt: skip
    head = struct.pack("<2IBBxxI", *map(int, v["version"]), 1, 5, v["tick"])
    imu = struct.pack("<13fh", *_f32(v["imu"]), v["imu_temp"])
    wire, c = head + imu, head + imu + b"\x00\x00"
    for i in range(N):
        record = struct.pack("<4f2hf2II4I", *_f32(v["f"][i]), *map(int, v["temp"][i]), *_f32(v["vol"][i : i + 1]),
                             *map(int, v["sensor"][i]), int(v["motorstate"][i]), *map(int, v["reserve"][i]))  # fmt: skip
        wire += struct.pack("<B", int(v["mode"][i]))
        wire += b"\x00" * (-len(wire) % 4) + record
        c += struct.pack("<Bxxx", int(v["mode"][i])) + record
    tail = struct.pack("<40B4I", *map(int, v["remote"]), *map(int, v["tail"]))
    c += tail + b"\x00" * 4
    crc = _crc_of_c_struct(c)
    return HEADER + wire + tail + struct.pack("<I", crc), v


def test_lowstate_built_by_hand_is_read_field_by_field() -> None:
    wire, v = _state_by_hand(np.random.default_rng(3))
    assert len(wire) == 2092
    msg = LowState()
    assert msg.load(wire) == OK
    assert int(msg.tick[0]) == v["tick"]
    np.testing.assert_array_equal(msg.modes, v["mode"])
    np.testing.assert_array_equal(msg.q, v["f"][:, 0])
    np.testing.assert_array_equal(msg.tau_est, v["f"][:, 3])
    np.testing.assert_array_equal(msg.temperature, v["temp"])
    np.testing.assert_array_equal(msg.motorstate, v["motorstate"])
    np.testing.assert_array_equal(msg.quaternion, v["imu"][:4])
    np.testing.assert_array_equal(msg.accelerometer, v["imu"][7:10])
    assert msg.seal() == wire  # and written back, byte for byte


def test_lowstate_matches_cyclone_serialisation_of_the_idl_types() -> None:
    pytest.importorskip("cyclonedds")
    from giwbc.hal.dds.idl import LowState_

    wire, v = _state_by_hand(np.random.default_rng(4))
    ref = LowState_.deserialize(wire)
    assert ref.tick == v["tick"] and ref.motor_state[34].motorstate == int(v["motorstate"][34])
    assert ref.serialize() == wire


def test_bad_crc_wrong_size_refused() -> None:
    wire, _ = _state_by_hand(np.random.default_rng(6))
    msg = LowState()
    bad = bytearray(wire)
    bad[200] ^= 0x10  # one bit of a motor's q
    assert msg.load(bytes(bad)) == BAD_CRC
    bad = bytearray(wire)
    bad[-1] ^= 0x01  # the CRC itself
    assert msg.load(bytes(bad)) == BAD_CRC
    assert msg.load(wire[:-8]) == BAD_SIZE
    assert msg.load(wire) == OK


def test_crc_is_unitrees_word_wise_crc32() -> None:
    rng = np.random.default_rng(7)
    for n in (8, 64, 1004, 2092):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert unitree_crc(data) == _crc_of_c_struct(data)
    # the documented algorithm is CRC-32/MPEG-2 over the words' big-endian bytes: its check value
    # for "12345678" fed as the words 0x31323334, 0x35363738
    assert crc32_reference([0x31323334, 0x35363738]) == _mpeg2(b"12345678")


def _mpeg2(data: bytes) -> int:
    """CRC-32/MPEG-2 byte-wise (check value of b"123456789": 0x0376E6E7)."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte << 24
        for _ in range(8):
            crc = ((crc << 1) ^ 0x04C11DB7) & 0xFFFFFFFF if crc & 0x80000000 else (crc << 1) & 0xFFFFFFFF
    return crc


def test_mpeg2_check_value() -> None:
    assert _mpeg2(b"123456789") == 0x0376E6E7
