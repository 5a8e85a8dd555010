"""MIT mode codec: exact bytes, quantization, clamping, special frames, reply variants, totality."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from giwbc.hal.frames import CAN_ERR_FLAG, FRAME, frames, frames_of
from giwbc.hal.motor import MotorConfig, MotorModel, Range
from giwbc.hal.protocols import (
    CORRUPT,
    ERROR_FRAME,
    REPLY,
    UNKNOWN,
    ActuatorProtocol,
    CanFrame,
    CanProtocolError,
    CommandValueError,
    CorruptFrameError,
    FrameLengthError,
    MitProtocol,
    MotorReply,
    ProtocolConfigError,
    UnknownMotorError,
    pack_command,
)
from giwbc.hal.protocols.mit import DAMIAO_STATES

# The reference ranges of the brief: P +-12.5, V +-65, KP 0..500, KD 0..5, T +-18.
REF = MotorModel(
    "ref", Range(-12.5, 12.5), Range(-65.0, 65.0), Range(0.0, 500.0), Range(0.0, 5.0), Range(-18.0, 18.0)
)
STEPS = [(r.max - r.min) / lv for r, lv in zip(REF.ranges, (65535, 4095, 4095, 4095, 4095))]


def motor(can_id: int = 1, reply: str = "original", model: MotorModel = REF, joint: str | None = None) -> MotorConfig:
    return MotorConfig(can_id, model, joint or f"j{can_id}", reply=reply)


def proto(*motors: MotorConfig, **kw) -> MitProtocol:
    return MitProtocol(motors or (motor(),), **kw)


# ----------------------------------------------------------------------------- commands
@pytest.mark.parametrize(
    "values, expected",
    [
        ((0.0, 0.0, 0.0, 0.0, 0.0), "7F FF 7F F0 00 00 07 FF"),
        # all fields at their range ends: p max, v min, kp max, kd max, t max
        ((12.5, -65.0, 500.0, 5.0, 18.0), "FF FF 00 0F FF FF FF FF"),
        # p=1: 13.5*65535/25 = 35388.9 -> 0x8A3D; v=5: 70*4095/130 = 2205 -> 0x89D;
        # kp=100 -> 819 = 0x333; kd=1 -> 0x333; t=-3: 15*4095/36 = 1706.25 -> 0x6AA
        ((1.0, 5.0, 100.0, 1.0, -3.0), "8A 3D 89 D3 33 33 36 AA"),
        # all minimum: p min, v max, kp 0, kd 0, t min
        ((-12.5, 65.0, 0.0, 0.0, -18.0), "00 00 FF F0 00 00 00 00"),
    ],
)
def test_command_known_bytes(values, expected):
    p = proto(motor(7))
    enc = p.encode_command(7, *values)
    assert enc.frame.arbitration_id == 7
    assert not enc.frame.is_extended_id
    assert enc.frame.data == bytes.fromhex(expected)
    assert enc.clamped == (False,) * 5
    assert pack_command(motor(7), *values)[0] == bytes.fromhex(expected)
    batch = p.encode_commands(*values)
    assert batch.data.tobytes() == bytes.fromhex(expected)
    assert batch.clamp_count == 0


def test_clamping_reports_fields():
    p = proto()
    enc = p.encode_command(1, 100.0, -1000.0, -5.0, 10.0, 1e9)
    assert enc.frame.data == bytes.fromhex("FF FF 00 00 00 FF FF FF")
    assert enc.clamped == (True, True, True, True, True)
    enc = p.encode_command(1, 0.0, 0.0, 0.0, 0.0, -18.5)
    assert enc.frame.data == bytes.fromhex("7F FF 7F F0 00 00 00 00")
    assert enc.clamped == (False, False, False, False, True)
    assert enc.clamped_fields == ("torque",)
    # infinities clamp like any out-of-range value; exact range ends are not clamped
    enc = p.encode_command(1, -math.inf, math.inf, 500.0, 0.0, 18.0)
    assert enc.clamped == (True, True, False, False, False)
    assert enc.frame.data == bytes.fromhex("00 00 FF FF FF 00 0F FF")


def test_vectorized_clamp_mask_and_broadcast():
    p = proto(motor(1), motor(2), motor(3))
    b = p.encode_commands([0.0, 13.0, -13.0], 0.0, [0.0, 0.0, 600.0], 0.0, [0.0, 0.0, 0.0])
    assert b.data.shape == (3, 8) and b.data.dtype == np.uint8
    assert b.clamped.tolist() == [[False] * 5, [True] + [False] * 4, [True, False, True, False, False]]
    assert b.clamp_count == 3
    assert [f.arbitration_id for f in b.frames()] == [1, 2, 3]
    assert b.frames()[0].data == bytes.fromhex("7F FF 7F F0 00 00 07 FF")


def test_nan_command_is_refused_not_encoded():
    p = proto(motor(1), motor(2))
    with pytest.raises(CommandValueError):
        p.encode_command(1, 0.0, math.nan, 0.0, 0.0, 0.0)
    with pytest.raises(CommandValueError, match=r"j2\.torque"):
        p.encode_commands(0.0, 0.0, 0.0, 0.0, [0.0, math.nan])


def test_special_frames():
    p = proto(motor(0x23))
    assert p.enter_motor_mode(0x23).data == bytes.fromhex("FF FF FF FF FF FF FF FC")
    assert p.exit_motor_mode(0x23).data == bytes.fromhex("FF FF FF FF FF FF FF FD")
    assert p.set_zero(0x23).data == bytes.fromhex("FF FF FF FF FF FF FF FE")
    assert p.clear_errors(0x23).data == bytes.fromhex("FF FF FF FF FF FF FF FB")
    assert p.set_zero(0x23).arbitration_id == 0x23
    assert p.decode_command(0x23, p.enter_motor_mode(0x23).data).special == "enter"
    assert p.decode_command(0x23, p.set_zero(0x23).data).special == "zero"
    with pytest.raises(UnknownMotorError):
        p.enter_motor_mode(0x24)


def test_zero_in_symmetric_range_ties_to_lower_code():
    # 0 -> 32767.5 exactly: the tie goes to the lower code, decoded within half a step.
    cmd = proto().decode_command(1, bytes.fromhex("7F FF 7F F0 00 00 07 FF"))
    assert cmd.position == pytest.approx(-STEPS[0] / 2, abs=1e-12)
    assert cmd.velocity == pytest.approx(-STEPS[1] / 2, abs=1e-12)
    assert cmd.kp == 0.0 and cmd.kd == 0.0


finite = dict(allow_nan=False, allow_infinity=False)


@settings(max_examples=300, deadline=None)
@given(
    st.floats(-12.5, 12.5, **finite),
    st.floats(-65, 65, **finite),
    st.floats(0, 500, **finite),
    st.floats(0, 5, **finite),
    st.floats(-18, 18, **finite),
)
def test_command_round_trip_within_half_step(pos, vel, kp, kd, tau):
    values = (pos, vel, kp, kd, tau)
    p = proto()
    enc = p.encode_command(1, *values)
    assert enc.clamped == (False,) * 5
    cmd = p.decode_command(1, enc.frame.data)
    got = (cmd.position, cmd.velocity, cmd.kp, cmd.kd, cmd.torque)
    for x, y, step in zip(values, got, STEPS):
        assert abs(x - y) <= step / 2 * (1 + 1e-9)
    # the vectorized encoder gives the same bytes
    assert p.encode_commands(*values).data.tobytes() == enc.frame.data


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-1e4, 1e4, **finite)] * 5), min_size=1, max_size=6))
def test_vectorized_encode_equals_scalar(rows):
    ms = [motor(i + 1) for i in range(len(rows))]
    p = MitProtocol(ms)
    cols = np.array(rows).T
    batch = p.encode_commands(*cols)
    for i, row in enumerate(rows):
        enc = p.encode_command(i + 1, *row)
        assert batch.data[i].tobytes() == enc.frame.data
        assert tuple(batch.clamped[i].tolist()) == enc.clamped


# ----------------------------------------------------------------------------- replies
def test_reply_original_known_bytes():
    p = proto(motor(1))
    r = p.decode(0, bytes.fromhex("01 FF FF 00 0F FF"))
    assert r == MotorReply(1, 12.5, -65.0, 18.0)
    r = p.decode(0, bytes.fromhex("01 00 00 FF F0 00"))
    assert (r.position, r.velocity, r.torque) == (-12.5, 65.0, -18.0)
    assert r.temperature is None and r.error_code is None and r.voltage is None and r.status is None
    assert p.encode_reply(1, 12.5, -65.0, 18.0).data == bytes.fromhex("01 FF FF 00 0F FF")


def test_reply_cubemars_known_bytes():
    p = proto(motor(5, "cubemars"))
    r = p.decode(0, bytes.fromhex("05 FF FF 00 0F FF 41 03"))
    assert (r.motor_id, r.position, r.velocity, r.torque) == (5, 12.5, -65.0, 18.0)
    assert r.temperature == 25.0  # 0x41 = 65, offset -40
    assert r.error_code == 3 and r.faulted
    frame = p.encode_reply(5, 12.5, -65.0, 18.0, temperature=25.0, error_code=3)
    assert frame.data == bytes.fromhex("05 FF FF 00 0F FF 41 03")


def test_reply_damiao_known_bytes():
    p = proto(motor(3, "damiao"))
    r = p.decode(0x13, bytes.fromhex("13 FF FF 00 0F FF 2D 32"))
    assert (r.motor_id, r.position, r.velocity, r.torque) == (3, 12.5, -65.0, 18.0)
    assert (r.status, r.error_code, r.temperature, r.rotor_temperature) == (1, 0, 45.0, 50.0)
    assert not r.faulted
    r = p.decode(0x13, bytes.fromhex("B3 FF FF 00 0F FF 2D 32"))  # state 0xB: MOS over-temperature
    assert (r.status, r.error_code, r.faulted) == (0xB, 0xB, True)
    frame = p.encode_reply(3, 12.5, -65.0, 18.0, temperature=45, rotor_temperature=50)
    assert frame.data == bytes.fromhex("13 FF FF 00 0F FF 2D 32")
    assert p.encode_reply(3, 0, 0, 0, error_code=0xB).data[0] == 0xB3


def test_reply_voltage_variant():
    p = proto(motor(9, "voltage"))
    r = p.decode(0, bytes.fromhex("09 FF FF 00 0F FF 60"))
    assert r.voltage == 24.0  # 0x60 = 96 counts * 0.25 V (documented assumption)
    assert proto(motor(9, "voltage"), voltage_lsb=0.5).decode(0, bytes.fromhex("09 FF FF 00 0F FF 60")).voltage == 48.0
    assert p.encode_reply(9, 12.5, -65.0, 18.0, voltage=24.0).data == bytes.fromhex("09 FF FF 00 0F FF 60")


def mixed_bus() -> MitProtocol:
    return MitProtocol(
        [motor(1, "original"), motor(2, "voltage"), motor(0x21, "cubemars"), motor(4, "damiao"), motor(5, "damiao")]
    )


def test_every_variant_round_trips_on_a_mixed_bus():
    p = mixed_bus()
    for m in p.motors:
        frame = p.encode_reply(m.can_id, 1.234, -4.5, 2.5, temperature=61, rotor_temperature=70, voltage=47.5)
        r = p.decode(frame.arbitration_id, frame.data)
        assert r.motor_id == m.can_id
        assert abs(r.position - 1.234) <= STEPS[0] / 2 * (1 + 1e-9)
        assert abs(r.velocity + 4.5) <= STEPS[1] / 2 * (1 + 1e-9)
        assert abs(r.torque - 2.5) <= STEPS[4] / 2 * (1 + 1e-9)
        expected_len = {"original": 6, "voltage": 7, "cubemars": 8, "damiao": 8}[m.reply]
        assert len(frame.data) == expected_len
        if m.reply == "cubemars":
            assert (r.temperature, r.error_code) == (61.0, 0)
        if m.reply == "damiao":
            assert (r.temperature, r.rotor_temperature, r.status) == (61.0, 70.0, 1)
        if m.reply == "voltage":
            assert r.voltage == 47.5


@settings(max_examples=200, deadline=None)
@given(
    st.sampled_from([1, 2, 0x21, 4, 5]),
    st.floats(-12.5, 12.5, **finite),
    st.floats(-65, 65, **finite),
    st.floats(-18, 18, **finite),
    st.integers(-40, 215),
    st.integers(0, 255),
    st.integers(0, 15),
)
def test_reply_round_trip_property(mid, pos, vel, tau, temp, err, state):
    p = mixed_bus()
    frame = p.encode_reply(
        mid, pos, vel, tau, temperature=temp, rotor_temperature=temp + 40, error_code=err, status=state
    )
    reply = p.motor(mid).reply
    if (reply == "cubemars" and err > 7) or (reply == "damiao" and state not in DAMIAO_STATES):
        with pytest.raises((CorruptFrameError, UnknownMotorError)):  # undefined codes are no reply
            p.decode(frame.arbitration_id, frame.data)
        return
    r = p.decode(frame.arbitration_id, frame.data)
    assert r.motor_id == mid
    for x, y, step in ((pos, r.position, STEPS[0]), (vel, r.velocity, STEPS[1]), (tau, r.torque, STEPS[4])):
        assert abs(x - y) <= step / 2 * (1 + 1e-9)
    if reply == "cubemars":
        assert (r.temperature, r.error_code) == (temp, err)
    elif reply == "damiao":
        assert (r.status, r.error_code) == (state, state if state >= 8 else 0)


# ------------------------------------------------------------------------------ errors
def test_decode_errors_are_typed():
    p = mixed_bus()
    with pytest.raises(UnknownMotorError):  # no byte 0: addressed to no motor (a CANopen SYNC)
        p.decode(0, b"")
    with pytest.raises(UnknownMotorError):  # 9 bytes, byte 0 of no motor
        p.decode(0, bytes(9))
    with pytest.raises(FrameLengthError):  # 9 bytes from motor 1
        p.decode(0, bytes([1]) + bytes(8))
    with pytest.raises(FrameLengthError, match="8 bytes"):
        p.decode(0, bytes.fromhex("21 00 00 00 00 00"))  # cubemars motor, 6 bytes
    with pytest.raises(UnknownMotorError):
        p.decode(0, bytes.fromhex("77 00 00 00 00 00"))
    with pytest.raises(UnknownMotorError):
        p.decode(0x100, bytes.fromhex("01 00 00 00 00 00"), is_extended_id=True)
    for bad_id in (-1, 0x800, 1.5, None, "1"):
        with pytest.raises(CorruptFrameError):
            p.decode(bad_id, bytes.fromhex("01 00 00 00 00 00"))
    for bad_data in (None, 5, "010203040506", [1, 2, 300], object()):
        with pytest.raises(CorruptFrameError):
            p.decode(0, bad_data)
    # bytes-likes are fine
    raw = bytes.fromhex("01 00 00 00 00 00")
    for ok in (bytearray(raw), memoryview(raw), list(raw)):
        assert p.decode(0, ok).motor_id == 1


def test_special_frame_is_not_a_reply():
    p = proto(motor(0xFF, "cubemars"))
    with pytest.raises(CorruptFrameError):
        p.decode(0, bytes.fromhex("FF FF FF FF FF FF FF FC"))
    assert p.decode(0, bytes.fromhex("FF FF FF FF FF FF FF 00")).motor_id == 0xFF


def test_host_id_filter():
    p = proto(motor(1), host_id=0)
    assert p.decode(0, bytes.fromhex("01 00 00 00 00 00")).motor_id == 1
    with pytest.raises(UnknownMotorError):
        p.decode(5, bytes.fromhex("01 00 00 00 00 00"))


def test_protocol_config_errors():
    with pytest.raises(ProtocolConfigError, match="cannot be told apart"):
        MitProtocol([motor(3, "damiao"), motor(0x13, "cubemars")])  # 0x13 = damiao state 1, id 3
    with pytest.raises(ProtocolConfigError, match="cannot be told apart"):
        MitProtocol([motor(3, "damiao"), motor(0x13, "damiao")])  # same low nibble
    MitProtocol([motor(3, "damiao"), motor(0x13, "original")])  # different lengths: fine
    with pytest.raises(ProtocolConfigError, match="byte 0"):
        MitProtocol([motor(0x100, "cubemars")])
    with pytest.raises(ProtocolConfigError, match="11-bit"):
        MitProtocol([motor(0x800, "damiao")])
    with pytest.raises(ProtocolConfigError, match="unknown MIT reply variant"):
        MitProtocol([motor(1, "robstride")])
    with pytest.raises(ProtocolConfigError, match="duplicate"):
        MitProtocol([motor(1), motor(1, joint="other")])


def test_decode_command_errors():
    p = proto(motor(1))
    with pytest.raises(UnknownMotorError):
        p.decode_command(2, bytes(8))
    with pytest.raises(FrameLengthError):
        p.decode_command(1, bytes(7))
    with pytest.raises(CorruptFrameError):
        p.decode_command(1, None)


motor_sets = st.lists(
    st.tuples(st.integers(0, 0xFF), st.sampled_from(["original", "voltage", "cubemars", "damiao"])),
    min_size=0,
    max_size=6,
    unique_by=lambda t: t[0],
)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(
    motor_sets,
    st.one_of(st.integers(-5, 0x20000005), st.none(), st.floats(allow_nan=True)),
    st.binary(min_size=0, max_size=8),
    st.booleans(),
)
def test_garbage_never_raises_anything_but_protocol_errors(specs, arb_id, data, extended):
    try:
        p = MitProtocol([motor(i, v) for i, v in specs])
    except ProtocolConfigError:
        assume(False)
    for fn in (p.decode, p.decode_command):
        try:
            out = fn(arb_id, data, extended)
        except CanProtocolError:
            continue
        assert out.motor_id in p.index
    try:
        r = p.decode(arb_id, data, extended)
    except CanProtocolError:
        return
    m = p.motor(r.motor_id)
    assert m.model.position.min <= r.position <= m.model.position.max
    assert m.model.velocity.min <= r.velocity <= m.model.velocity.max
    assert m.model.torque.min <= r.torque <= m.model.torque.max


frame_records = st.lists(
    st.tuples(
        st.sampled_from([0, 1, 2, 3, 4, 5, 0x7FF, 0x80000001, 0x40000001, 0x20000000]) | st.integers(0, 0xFFFFFFFF),
        st.integers(0, 15),  # payload length as a struct can_frame says it (> 8: not a classic frame)
        st.binary(min_size=8, max_size=8) | st.sampled_from([b"\xff" * 7 + bytes([k]) for k in range(0xFA, 0x100)]),
        st.sampled_from([1, 2, 3, 0x13, 0xA3, 0xFF, 0x05]),  # byte 0: ids, Damiao states, strangers
    ),
    min_size=1,
    max_size=16,
)


def _records(rows) -> np.ndarray:
    batch = np.zeros(len(rows), dtype=FRAME)
    for k, (can_id, length, data, b0) in enumerate(rows):
        batch[k]["can_id"] = can_id
        batch[k]["len"] = length
        batch[k]["data"] = np.frombuffer(bytes([b0]) + data[1:] if data[:7] != b"\xff" * 7 else data, dtype=np.uint8)
    return batch


@settings(max_examples=300, deadline=None)
@given(frame_records, st.sampled_from([None, 0, 0x7FF]))
def test_vectorized_decode_equals_decode_frame_by_frame(rows, host_id):
    """decode_frames (vectorized) gives what decode() gives for each frame: the same verdict
    (reply, unknown, corrupt, error frame), the same MotorReply, bit for bit."""
    p = MitProtocol(mixed_bus().motors, host_id=host_id)
    batch = _records(rows)
    fast = p.decode_frames(batch)
    reference = ActuatorProtocol.decode_frames(p, batch)  # one decode() per frame
    assert fast.verdict.tolist() == reference.verdict.tolist()
    assert fast.index.tolist() == reference.index.tolist()
    for k in range(len(batch)):
        assert fast.reply(k) == reference.reply(k)


def test_decode_frames_verdicts_match_the_exceptions():
    p = MitProtocol([*mixed_bus().motors, motor(0xFF, "cubemars")])
    good = p.encode_reply(2, 0.5, -1.0, 0.25)
    batch = frames_of([
        good,
        CanFrame(good.arbitration_id, good.data[:3]),  # too short for motor 2's variant: corrupt
        CanFrame(good.arbitration_id, bytes([0x42]) + good.data[1:]),  # no such motor: unknown
        CanFrame(0x123, good.data, is_extended_id=True),  # extended: unknown
        CanFrame(good.arbitration_id, b"\xff" * 7 + b"\xfc"),  # motor 0xFF's length, but enter-motor-mode: corrupt
    ])  # fmt: skip
    batch = np.concatenate([batch, frames([0], np.zeros((1, 8)))])
    batch[-1]["can_id"] |= CAN_ERR_FLAG
    decoded = p.decode_frames(batch)
    assert decoded.verdict.tolist() == [REPLY, CORRUPT, UNKNOWN, UNKNOWN, CORRUPT, ERROR_FRAME]
    assert decoded.reply(0) == p.decode(good.arbitration_id, good.data)
    assert decoded.index.tolist() == [p.index[2], -1, -1, -1, -1, -1]
