"""The MIT codec and the decoded-reply batches at their edges: what each error says (a log line
is all an operator gets), configuration limits, values at and beyond their ranges, integer ids of
numpy types, and the batch operations (rows, selection, concatenation) the bus loop relies on."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.hal.frames import frames
from giwbc.hal.motor import MotorConfig, MotorModel, Range
from giwbc.hal.protocols import (
    CORRUPT,
    REPLY,
    UNKNOWN,
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
from giwbc.hal.protocols.base import CommandBatch, DecodedReplies
from giwbc.hal.protocols.multibus import MultiBusCodec

REF = MotorModel("ref", Range(-12.5, 12.5), Range(-65.0, 65.0), Range(0.0, 500.0), Range(0.0, 5.0), Range(-18.0, 18.0))


def motor(can_id: int = 1, reply: str = "original", joint: str | None = None) -> MotorConfig:
    return MotorConfig(can_id, REF, joint or f"j{can_id}", reply=reply)


# --- decoded batches ---------------------------------------------------------------------------
REPLIES = [
    MotorReply(3, 1.0, -2.0, 0.5, temperature=40.0, error_code=0, voltage=24.5),
    None,
    MotorReply(7, -1.0, 2.0, -0.5, rotor_temperature=55.0, error_code=9, status=2),
]


def batch() -> DecodedReplies:
    return DecodedReplies.from_replies([REPLY, CORRUPT, REPLY], [0, -1, 1], REPLIES)


def test_rows_built_from_replies_give_the_replies_back() -> None:
    d = batch()
    assert len(d) == 3 and d.count(REPLY) == 2 and d.count(CORRUPT) == 1 and d.count(UNKNOWN) == 0
    assert d.valid.tolist() == [True, False, True]
    assert d.reply(0) == REPLIES[0] and d.reply(1) is None and d.reply(2) == REPLIES[2]
    assert d.motor_id.tolist() == [3, -1, 7] and d.index.tolist() == [0, -1, 1]
    np.testing.assert_array_equal(d.position, [1.0, np.nan, -1.0])
    np.testing.assert_array_equal(d.velocity, [-2.0, np.nan, 2.0])
    np.testing.assert_array_equal(d.torque, [0.5, np.nan, -0.5])
    np.testing.assert_array_equal(d.temperature, [40.0, np.nan, np.nan])
    np.testing.assert_array_equal(d.rotor_temperature, [np.nan, np.nan, 55.0])
    np.testing.assert_array_equal(d.voltage, [24.5, np.nan, np.nan])
    assert d.error_code.tolist() == [0, -1, 9] and d.status.tolist() == [-1, -1, 2]
    for name, kind in (("verdict", "i"), ("index", "i"), ("motor_id", "i"), ("error_code", "i"), ("status", "i"),
                       ("state", "f"), ("temperature", "f"), ("rotor_temperature", "f"), ("voltage", "f")):  # fmt: skip
        assert getattr(d, name).dtype.kind == kind, name
    assert d.state.shape == (3, 3)
    assert len(DecodedReplies.from_replies([], [], [])) == 0


def test_taking_and_concatenating_rows() -> None:
    d = batch()
    picked = d.take(np.array([2, 0]))
    assert picked.reply(0) == REPLIES[2] and picked.reply(1) == REPLIES[0] and len(picked) == 2
    both = DecodedReplies.concatenate([d, d], [0, 10])
    assert both.index.tolist() == [0, -1, 1, 10, -1, 11]  # invalid rows stay -1
    assert [both.reply(k) for k in range(6)] == REPLIES + REPLIES
    assert DecodedReplies.concatenate([d, d]).index.tolist() == [0, -1, 1, 0, -1, 1]
    assert len(DecodedReplies.concatenate([])) == 0


def test_a_command_batch_splits_into_frames() -> None:
    p = MitProtocol([motor(1), motor(2)])
    commands = p.encode_commands([0.0, 1.0], 0.0, 0.0, 0.0, [0.0, 99.0])
    assert len(commands) == 2 and commands.clamp_count == 1
    frames = commands.frames()
    assert [f.arbitration_id for f in frames] == [1, 2]
    assert [f.data for f in frames] == [p.encode_command(i, *v).frame.data for i, v in ((1, (0, 0, 0, 0, 0)), (2, (1, 0, 0, 0, 99)))]
    assert all(not f.is_extended_id for f in frames)
    empty = CommandBatch(np.zeros(0, np.int64), np.zeros((0, 8), np.uint8), np.zeros((0, 5), bool))
    assert len(empty) == 0 and empty.frames() == []


# --- configuration -----------------------------------------------------------------------------
def test_protocol_configuration_limits_and_messages() -> None:
    with pytest.raises(ProtocolConfigError, match=r"^host_id must be a standard 11-bit id, got 2048$"):
        MitProtocol([motor()], host_id=0x800)
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ProtocolConfigError, match=r"^voltage_lsb must be > 0, got "):
            MitProtocol([motor()], voltage_lsb=bad)
    with pytest.raises(ProtocolConfigError, match=r"^motor 'j1': unknown MIT reply variant 'nope'; known: original, voltage, cubemars, damiao"):
        MitProtocol([motor(1, "nope")])
    # The whole 11-bit range, both ends, for a variant whose replies carry 4 bits of the id.
    assert MitProtocol([motor(0, "damiao"), motor(0x7FF, "damiao", "far")]).index == {0: 0, 0x7FF: 1}
    with pytest.raises(ProtocolConfigError, match=r"^motor 'big': MIT mode uses 11-bit ids, got 0x800$"):
        MitProtocol([motor(0x800, "damiao", "big")])


# --- commands ----------------------------------------------------------------------------------
def test_command_errors_name_what_is_wrong() -> None:
    p = MitProtocol([motor(1, joint="knee"), motor(2, joint="hip")])
    with pytest.raises(CommandValueError, match=r"^NaN in commands: knee\.velocity, hip\.kd$"):
        p.encode_commands([0.0, 0.0], [np.nan, 0.0], 0.0, [0.0, np.nan], 0.0)
    with pytest.raises(CommandValueError, match=r"^NaN in command fields \{'position': 0\.0, 'velocity': nan"):
        pack_command(motor(), 0.0, math.nan, 0.0, 0.0, 0.0)
    for make in (lambda: p.encode_command(9, 0, 0, 0, 0, 0), lambda: p.enter_motor_mode(9), lambda: p.encode_reply(9, 0, 0, 0)):
        with pytest.raises(UnknownMotorError, match=r"^no motor with id 9 on this bus$"):
            make()
    with pytest.raises(CommandValueError, match=r"^NaN in reply for motor 1$"):
        p.encode_reply(1, math.nan, 0.0, 0.0)


def test_reply_values_beyond_the_range_saturate_at_its_ends() -> None:
    p = MitProtocol([motor()])
    low = p.decode(0, p.encode_reply(1, -100.0, -100.0, -100.0).data)
    assert (low.position, low.velocity, low.torque) == (-12.5, -65.0, -18.0)
    high = p.decode(0, p.encode_reply(1, 100.0, 100.0, 100.0).data)
    assert (high.position, high.velocity, high.torque) == (12.5, 65.0, 18.0)


def test_reply_encoding_limits_and_defaults() -> None:
    cubemars = MitProtocol([motor(1, "cubemars")])
    with pytest.raises(ValueError, match=r"^error code must be 0\.\.255, got 256$"):
        cubemars.encode_reply(1, 0, 0, 0, error_code=256)
    assert cubemars.decode(0, cubemars.encode_reply(1, 0, 0, 0, error_code=7).data).error_code == 7
    with pytest.raises(CorruptFrameError, match="no defined error code"):  # encodable, but no drive sends it
        cubemars.decode(0, cubemars.encode_reply(1, 0, 0, 0, error_code=255).data)
    damiao = MitProtocol([motor(1, "damiao")])
    with pytest.raises(ValueError, match=r"^Damiao state must be 0\.\.15, got 16$"):
        damiao.encode_reply(1, 0, 0, 0, status=16)
    assert damiao.decode(0, damiao.encode_reply(1, 0, 0, 0, status=14).data).status == 14  # 15 is undefined
    reply = damiao.decode(0, damiao.encode_reply(1, 0, 0, 0).data)  # defaults: enabled, 25 °C
    assert (reply.status, reply.error_code, reply.temperature, reply.rotor_temperature) == (1, 0, 25.0, 25.0)
    voltage = MitProtocol([motor(1, "voltage")])
    assert voltage.decode(0, voltage.encode_reply(1, 0, 0, 0).data).voltage == pytest.approx(24.0, abs=0.2)
    assert MitProtocol([motor()]).encode_reply(1, 0, 0, 0).arbitration_id == 0  # the host id by default
    assert MitProtocol([motor()], host_id=5).encode_reply(1, 0, 0, 0).arbitration_id == 5
    assert MitProtocol([motor()]).encode_reply(1, 0, 0, 0, arbitration_id=0x33).arbitration_id == 0x33


def test_damiao_error_states_start_at_eight() -> None:
    p = MitProtocol([motor(1, "damiao")])
    for state, error in ((0, 0), (1, 0), (8, 8), (9, 9), (14, 14)):
        reply = p.decode(0, p.encode_reply(1, 0, 0, 0, status=state).data)
        assert (reply.status, reply.error_code) == (state, error)
    for undefined in (2, 7, 15):  # no such state in the firmware: not a reply
        with pytest.raises(UnknownMotorError):
            p.decode(0, p.encode_reply(1, 0, 0, 0, status=undefined).data)


# --- decoding ----------------------------------------------------------------------------------
def test_decode_errors_say_why() -> None:
    p = MitProtocol([motor(1), motor(0x22, "cubemars")], host_id=None)
    data = p.encode_reply(1, 0, 0, 0).data
    cases = [
        ((1.5, data), CorruptFrameError, r"^arbitration id must be an integer, got float$"),
        ((True, data), CorruptFrameError, r"^arbitration id must be an integer, got bool$"),
        ((0x800, data), CorruptFrameError, r"^arbitration id 0x800 out of range$"),
        ((0, b""), UnknownMotorError, r"^a frame without payload \(a CANopen SYNC, ...\) names no motor$"),
        ((0, bytes([1])), FrameLengthError, r"^motor id 1 replies with 6 bytes \(original\), got 1$"),
        ((0, bytes(8)), UnknownMotorError, r"^no motor on this bus replies with byte 0 = 0x00 in 8 bytes$"),
        ((0, bytes([0x22]) + bytes(5)), FrameLengthError, r"^motor id 34 replies with 8 bytes \(cubemars\), got 6$"),
        ((0, bytes([0xFF] * 7 + [0xFC])), UnknownMotorError, r"byte 0 = 0xFF"),
        ((0, 5), CorruptFrameError, r"^frame data must be bytes, got int$"),
    ]
    for args, error, message in cases:
        with pytest.raises(error, match=message):
            p.decode(*args)
    with pytest.raises(UnknownMotorError, match=r"^extended frame 0x100 is not an MIT reply$"):
        p.decode(0x100, data, is_extended_id=True)
    with pytest.raises(UnknownMotorError, match=r"^extended frame 0x1FFFFFFF is not an MIT reply$"):
        p.decode(0x1FFFFFFF, data, is_extended_id=True)
    with pytest.raises(CorruptFrameError, match=r"^arbitration id 0x20000000 out of range$"):
        p.decode(0x20000000, data, is_extended_id=True)
    hosted = MitProtocol([motor(1)], host_id=3)
    with pytest.raises(UnknownMotorError, match=r"^frame id 0x2 is not the host id 0x3$"):
        hosted.decode(2, data)
    special = MitProtocol([motor(0xFF, "cubemars")])
    with pytest.raises(CorruptFrameError, match=r"^a special command frame, not a reply$"):
        special.decode(0, bytes([0xFF] * 7 + [0xFC]))
    with pytest.raises(CorruptFrameError, match=r"^undecodable input: TypeError: "):
        p.decode(0, [1, "x"])


def test_numpy_integer_ids_decode_like_python_ints() -> None:
    p = MitProtocol([motor(1)], host_id=2)
    data = p.encode_reply(1, 1.0, 2.0, 3.0).data
    assert p.decode(np.int64(2), data) == p.decode(2, data)
    assert p.decode(np.uint16(2), data).motor_id == 1


def test_command_decoding_errors_and_specials() -> None:
    p = MitProtocol([motor(1)])
    frame = p.encode_command(1, 1.0, 2.0, 3.0, 0.5, -1.0).frame
    command = p.decode_command(1, frame.data)
    assert command.motor_id == 1 and command.special is None
    assert command.position == pytest.approx(1.0, abs=2e-4) and command.kp == pytest.approx(3.0, abs=0.07)
    enter = p.decode_command(1, p.enter_motor_mode(1).data)
    assert enter.motor_id == 1 and enter.special == "enter"
    assert all(math.isnan(x) for x in (enter.position, enter.velocity, enter.kp, enter.kd, enter.torque))
    with pytest.raises(UnknownMotorError, match=r"^extended frames are not MIT commands$"):
        p.decode_command(1, frame.data, is_extended_id=True)
    with pytest.raises(UnknownMotorError, match=r"^no motor with id 2 on this bus$"):
        p.decode_command(2, frame.data)
    with pytest.raises(UnknownMotorError, match=r"^no motor with id '1' on this bus$"):
        p.decode_command("1", frame.data)
    with pytest.raises(FrameLengthError, match=r"^MIT commands have 8 bytes, got 6$"):
        p.decode_command(1, frame.data[:6])
    with pytest.raises(CorruptFrameError, match=r"^undecodable input: TypeError: "):
        p.decode_command(1, [1, "x"])


# --- the vectorized decoder on the rows the random tests rarely draw ----------------------------
def decode_rows(p: MitProtocol, rows: list[tuple[int, bytes]]):
    data = np.zeros((len(rows), 8), np.uint8)
    for k, (_, payload) in enumerate(rows):
        data[k, : len(payload)] = list(payload)
    batch = frames([a for a, _ in rows], data, lengths=[len(payload) for _, payload in rows])
    return p.decode_frames(batch)


def test_vectorized_special_frame_detection_matches_the_scalar_one() -> None:
    p = MitProtocol([motor(0xFF, "cubemars", "hip"), motor(1, "damiao", "knee"), motor(3, "original", "ankle")])
    rows = [
        (0, bytes([0xFF] * 7 + [0xFC])),  # enter motor mode: a special frame, corrupt as a reply
        (0, bytes([0xFF] * 7 + [0xFB])),  # clear errors
        (0, bytes([0xFF] * 7 + [0xFE])),  # set zero
        (0, bytes([0xFF, 1, 2, 3, 4, 5, 6, 0x07])),  # a real reply of motor 0xFF (error code 7)
        (0, bytes([0xFF] * 7 + [0x05])),  # all FF but not a special code: a real reply (error code 5)
    ]
    decoded = decode_rows(p, rows)
    assert decoded.verdict.tolist() == [CORRUPT, CORRUPT, CORRUPT, REPLY, REPLY]
    assert decoded.motor_id.tolist() == [-1, -1, -1, 0xFF, 0xFF] and decoded.index.tolist() == [-1, -1, -1, 0, 0]
    assert decoded.error_code.tolist()[:3] == [-1, -1, -1] and decoded.status.tolist()[:3] == [-1, -1, -1]
    for k, (arbitration_id, payload) in enumerate(rows):
        if decoded.verdict[k] == REPLY:
            assert decoded.reply(k) == p.decode(arbitration_id, payload)
        else:
            with pytest.raises(CorruptFrameError):
                p.decode(arbitration_id, payload)
    elsewhere = MitProtocol([motor(1)])  # no motor 0xFF: a special frame is simply not a reply from here
    assert decode_rows(elsewhere, [(0, bytes([0xFF] * 7 + [0xFC]))]).verdict.tolist() == [UNKNOWN]


def test_vectorized_error_and_status_fields_per_variant() -> None:
    p = MitProtocol([motor(0x21, "cubemars", "a"), motor(2, "damiao", "b"), motor(3, "original", "c")])
    rows = [(0, p.encode_reply(0x21, 0, 0, 0, error_code=7, temperature=40.0).data),
            (0, p.encode_reply(2, 0, 0, 0, status=9, temperature=30.0, rotor_temperature=50.0).data),
            (0, p.encode_reply(2, 0, 0, 0, status=1).data),
            (0, p.encode_reply(3, 0, 0, 0).data)]  # fmt: skip
    decoded = decode_rows(p, rows)
    assert decoded.error_code.tolist() == [7, 9, 0, -1] and decoded.status.tolist() == [-1, 9, 1, -1]
    assert decoded.error_code.dtype.kind == "i" and decoded.status.dtype.kind == "i"
    np.testing.assert_array_equal(decoded.rotor_temperature, [np.nan, 50.0, 25.0, np.nan])
    assert [decoded.reply(k) for k in range(4)] == [p.decode(a, d) for a, d in rows]
    plain = MitProtocol([motor(3)])  # no variant with an error field
    only = decode_rows(plain, [(0, plain.encode_reply(3, 0, 0, 0).data)])
    assert only.error_code.tolist() == [-1] and only.status.tolist() == [-1] and only.error_code.dtype == np.int64


def test_reply_bytes_saturate_and_batches_keep_the_extended_flag() -> None:
    volts = MitProtocol([motor(1, "voltage")])
    assert volts.decode(0, volts.encode_reply(1, 0, 0, 0, voltage=1e6).data).voltage == pytest.approx(255 * volts.voltage_lsb)
    assert volts.decode(0, volts.encode_reply(1, 0, 0, 0, voltage=math.nan).data).voltage == 0.0
    extended = CommandBatch(np.array([5]), np.zeros((1, 8), np.uint8), np.zeros((1, 5), bool), is_extended_id=True)
    assert extended.frames()[0].is_extended_id is True
    from giwbc.hal.protocols import protocol_class

    assert protocol_class("mit") is MitProtocol
    with pytest.raises(ValueError, match=r"^unknown actuator protocol 'can2'; known: mit$"):
        protocol_class("can2")
    with pytest.raises(UnknownMotorError, match=r"^no motor with id 4 on this bus$"):
        MitProtocol([motor(1)]).motor(4)
    from giwbc.hal.protocols.multibus import MultiBusCodec

    with pytest.raises(ValueError, match=r"^special frames are \('enter', 'exit', 'zero'\), got 'boot'$"):
        MultiBusCodec([MitProtocol([motor(1)])]).special_frames("boot")


def test_a_frame_that_is_not_from_here_names_no_motor() -> None:
    """A frame that no motor of this bus sends decodes as UNKNOWN with motor id -1 (not some
    motor's id)."""
    p = MitProtocol([motor(1), motor(2)])
    decoded = decode_rows(p, [(0, bytes([0x09, 0, 0, 0, 0, 0])), (0, p.encode_reply(2, 0.0, 0.0, 0.0).data)])
    assert decoded.verdict.tolist() == [UNKNOWN, REPLY]
    assert decoded.motor_id.tolist() == [-1, 2] and decoded.index.tolist() == [-1, 1]


def test_a_reply_on_another_motors_command_id_is_traffic_for_that_motor() -> None:
    """Motor 1's reply bytes on arbitration id 2 (motor 2's command id) are not motor 1's reply;
    on its own id, or the host id 0, they are."""
    p = MitProtocol([motor(1), motor(2)])
    data = p.encode_reply(1, 0.5, 0.0, 0.0).data
    with pytest.raises(UnknownMotorError, match=r"^frame id 0x2 commands motor 2: not a reply of motor 1$"):
        p.decode(2, data)
    assert p.decode(1, data).motor_id == 1 and p.decode(0, data).position == pytest.approx(0.5, abs=1e-3)
    assert decode_rows(p, [(2, data), (1, data), (0, data)]).verdict.tolist() == [UNKNOWN, REPLY, REPLY]
    second = p.encode_reply(2, 0.5, 0.0, 0.0).data  # the first motor's command id is a clash too
    assert decode_rows(p, [(1, second), (2, second)]).verdict.tolist() == [UNKNOWN, REPLY]


def test_command_id_clashes_are_per_bus() -> None:
    """Two buses with motors 1 and 2 each: on either bus, motor 1's reply on id 2 is traffic for
    motor 2 of that bus; on its own id it is motor 1's reply of that bus (index across buses)."""
    codec = MultiBusCodec([MitProtocol([motor(1, joint="a1"), motor(2, joint="a2")]),
                           MitProtocol([motor(1, joint="b1"), motor(2, joint="b2")])])  # fmt: skip
    data = MitProtocol([motor(1)]).encode_reply(1, 0.5, 0.0, 0.0).data
    rows = [(2, 1), (1, 1), (2, 0), (1, 0), (0, 1)]  # (arbitration id, bus)
    payload = np.zeros(8, np.uint8)
    payload[: len(data)] = list(data)
    batch = frames([a for a, _ in rows], np.tile(payload, (len(rows), 1)), lengths=len(data))
    decoded = codec.decode_replies([b for _, b in rows], batch)
    assert decoded.verdict.tolist() == [UNKNOWN, REPLY, UNKNOWN, REPLY, REPLY]
    assert decoded.index.tolist() == [-1, 2, -1, 0, 2]


def test_junk_id_bits_short_frames_and_damiao_error_states() -> None:
    """A standard frame with id bits above 0x7FF is corrupt, as the scalar decoder says; so is a
    1-byte frame that starts with a motor's id; a Damiao state of 8 or more is its error code."""
    p = MitProtocol([motor(1), motor(2, "damiao")])
    data = p.encode_reply(1, 0.5, 0.0, 0.0).data
    with pytest.raises(CorruptFrameError):
        p.decode(0x801, data)
    with pytest.raises(CanProtocolError):
        p.decode(0, data[:1])
    errors = [p.encode_reply(2, 0.0, 0.0, 0.0, status=state).data for state in (1, 8, 9)]
    decoded = decode_rows(p, [(0x801, data), (0, data[:1])] + [(0, e) for e in errors])
    assert decoded.verdict.tolist() == [CORRUPT, CORRUPT, REPLY, REPLY, REPLY]
    assert decoded.error_code.tolist()[2:] == [0, 8, 9] and decoded.status.tolist()[2:] == [1, 8, 9]


def test_a_command_field_that_is_not_a_number_is_named() -> None:
    p = MitProtocol([motor(1)])
    with pytest.raises(CommandValueError, match=r"^command field kd must be a real number, got str '2'$"):
        p.encode_command(1, 0.0, 0.0, 10.0, "2", 0.0)
    with pytest.raises(CommandValueError, match=r"^command field position must be a real number, got bool True$"):
        p.encode_command(1, True, 0.0, 10.0, 1.0, 0.0)


def test_an_object_array_of_numbers_encodes_like_the_floats() -> None:
    """Numbers gathered in an object array (e.g. from a list of mixed Python and numpy numbers)
    are still numbers; a bool among them is not."""
    p = MitProtocol([motor(1), motor(2)])
    mixed = np.array([0.5, np.int64(-1)], dtype=object)
    expected = p.encode_commands([0.5, -1.0], 0.0, 10.0, 1.0, 0.0)
    assert p.encode_commands(mixed, 0.0, 10.0, 1.0, 0.0).data.tolist() == expected.data.tolist()
    with pytest.raises(CommandValueError, match=r"^command field position must be real numbers"):
        p.encode_commands(np.array([0.5, True], dtype=object), 0.0, 10.0, 1.0, 0.0)


def test_numbers_beyond_any_float_and_ragged_arrays_are_named() -> None:
    p = MitProtocol([motor(1), motor(2)])
    with pytest.raises(CommandValueError, match=r"^command field velocity = 10{400} is beyond any float \(clamping needs a number\)$"):
        p.encode_command(1, 0.0, 10**400, 10.0, 1.0, 0.0)
    with pytest.raises(CommandValueError, match=r"^command field torque: a value is beyond any float$"):
        p.encode_commands(0.0, 0.0, 10.0, 1.0, np.array([1, 10**400], dtype=object))
    with pytest.raises(CommandValueError, match=r"^command field kp: not an array of real numbers \("):
        p.encode_commands(0.0, 0.0, [[1.0, 2.0], [3.0]], 1.0, 0.0)


def test_a_command_frame_is_special_only_with_seven_ff_bytes_and_a_special_code() -> None:
    """What a motor does with a frame: FF x 7 then FB..FE is a special command; the same code after
    other bytes, or FF x 7 then another code, is an ordinary command (its fields decoded)."""
    p = MitProtocol([motor(1)])
    assert p.decode_command(1, bytes([0xFF] * 7 + [0xFC])).special == "enter"
    for data in (bytes([0x00] * 7 + [0xFC]), bytes([0xFF] * 7 + [0x05])):
        command = p.decode_command(1, data)
        assert command.special is None and math.isfinite(command.position)
    with pytest.raises(UnknownMotorError, match=r"^no motor with id 1\.0 on this bus$"):
        p.decode_command(1.0, bytes([0xFF] * 7 + [0xFC]))  # an arbitration id is an integer


def test_reply_temperatures_saturate_at_zero_and_keep_zero() -> None:
    """An emulated Damiao reply carries 0 °C as 0 and a sub-zero temperature saturated to 0 (a byte)."""
    p = MitProtocol([motor(1, "damiao")])
    for temperature, expected in ((0.0, 0.0), (-5.0, 0.0), (1.0, 1.0)):
        reply = p.decode(0, p.encode_reply(1, 0.0, 0.0, 0.0, temperature=temperature, rotor_temperature=temperature).data)
        assert reply.temperature == expected and reply.rotor_temperature == expected
