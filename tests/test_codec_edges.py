"""MIT codec edges (issue 13, items 7 and 8): foreign traffic, undefined codes, junk id bits, bad
command values, many motors, and a seeded fuzz over every decode path against an independent
oracle of what a reply is."""

from __future__ import annotations

import numpy as np
import pytest

from giwbc.hal.frames import CAN_EFF_FLAG, CAN_ERR_FLAG, CAN_RTR_FLAG, FRAME, frames, frames_of
from giwbc.hal.hardware import load_hardware
from giwbc.hal.motor import MotorConfig, MotorModel, Range
from giwbc.hal.protocols import (
    CORRUPT,
    ERROR_FRAME,
    REPLY,
    UNKNOWN,
    ActuatorProtocol,
    CanFrame,
    CommandValueError,
    CorruptFrameError,
    MitProtocol,
    MitReplyDecoder,
    UnknownMotorError,
)
from giwbc.hal.protocols.mit import CUBEMARS_ERRORS, DAMIAO_STATES, REPLY_VARIANTS
from giwbc.hal.protocols.multibus import MultiBusCodec

REF = MotorModel("ref", Range(-12.5, 12.5), Range(-65.0, 65.0), Range(0.0, 500.0), Range(0.0, 5.0), Range(-18.0, 18.0))
VARIANTS = ("original", "voltage", "cubemars", "damiao")


def motor(can_id: int, reply: str = "original", joint: str | None = None) -> MotorConfig:
    return MotorConfig(can_id, REF, joint or f"j{can_id}", reply=reply)


def mixed_bus(**kw) -> MitProtocol:
    return MitProtocol([motor(1, "original"), motor(2, "voltage"), motor(0x21, "cubemars"), motor(4, "damiao"), motor(5, "damiao")], **kw)


def verdicts_on_every_path(p: MitProtocol, batch: np.ndarray) -> list[list[int]]:
    """The verdicts of the reference path (one decode() per frame), decode_frames, a one-bus
    MitReplyDecoder and a MultiBusCodec with this bus second."""
    other = MitProtocol([motor(9, "cubemars")])
    bus = np.ones(len(batch), dtype=np.int64)
    return [
        ActuatorProtocol.decode_frames(p, batch).verdict.tolist(),
        p.decode_frames(batch).verdict.tolist(),
        MitReplyDecoder([p]).decode(np.zeros(len(batch), dtype=np.int64), batch).verdict.tolist(),
        MultiBusCodec([other, p]).decode_replies(bus, batch).verdict.tolist(),
    ]


# ----------------------------------------------------------------------------- foreign traffic
def test_a_zero_byte_frame_is_foreign_not_corrupt():
    """A CANopen SYNC (id 0x80, no payload) names no motor: unknown on every path, never corrupt."""
    p = mixed_bus()
    with pytest.raises(UnknownMotorError):
        p.decode(0x80, b"")
    sync = frames_of([CanFrame(0x80, b""), CanFrame(0, b""), CanFrame(0x701, b"\x7f")])  # SYNC, empty, a heartbeat
    assert verdicts_on_every_path(p, sync) == [[UNKNOWN] * 3] * 4


def test_undefined_damiao_states_are_no_reply():
    """Byte 0 = state << 4 | id: states 2..7 and 15 are undefined, so byte 0 names no motor."""
    p = mixed_bus()
    for state in range(16):
        frame = p.encode_reply(4, 0.5, 1.0, -2.0, status=state)
        batch = frames_of([frame])
        if state in DAMIAO_STATES:
            r = p.decode(frame.arbitration_id, frame.data)
            assert (r.status, r.error_code) == (state, state if state >= 8 else 0)
            assert verdicts_on_every_path(p, batch) == [[REPLY]] * 4
        else:
            with pytest.raises(UnknownMotorError):
                p.decode(frame.arbitration_id, frame.data)
            assert verdicts_on_every_path(p, batch) == [[UNKNOWN]] * 4


def test_an_undefined_cubemars_error_byte_is_corrupt():
    p = mixed_bus()
    for code in (0, 7, 8, 0x80, 0xFF):
        frame = p.encode_reply(0x21, 0.5, 1.0, -2.0, error_code=code)
        if code in CUBEMARS_ERRORS:
            assert p.decode(frame.arbitration_id, frame.data).error_code == code
            continue
        with pytest.raises(CorruptFrameError):
            p.decode(frame.arbitration_id, frame.data)
        assert verdicts_on_every_path(p, frames_of([frame])) == [[CORRUPT]] * 4


def test_junk_in_id_bits_11_to_28_is_rejected_like_the_scalar_decoder():
    """A standard frame record whose can_id has bits 11..28 set is no valid frame: every batch path
    says corrupt, as decode() does for the raw id."""
    p = mixed_bus()
    good = p.encode_reply(1, 0.5, 1.0, -2.0)
    batch = frames_of([good, good, good])
    batch["can_id"][1] |= 0x800
    batch["can_id"][2] |= 0x1FFFF800
    with pytest.raises(CorruptFrameError):
        p.decode(int(batch["can_id"][1]), good.data)
    assert verdicts_on_every_path(p, batch) == [[REPLY, CORRUPT, CORRUPT]] * 4
    batch["can_id"][1:] |= CAN_EFF_FLAG  # the same bits in an extended frame: a foreign id
    assert verdicts_on_every_path(p, batch) == [[REPLY, UNKNOWN, UNKNOWN]] * 4


def test_another_motors_command_id_is_traffic_for_it_not_a_reply():
    """A reply never carries another motor's command id (that motor would take it as a command):
    such a frame is unknown. A motor's own id stays allowed (CubeMars replies with it)."""
    p = MitProtocol([motor(1, "cubemars"), motor(2, "cubemars")])
    reply_of_1 = p.encode_reply(1, 0.5, 1.0, -2.0).data
    assert p.decode(0, reply_of_1).motor_id == 1
    assert p.decode(1, reply_of_1).motor_id == 1
    with pytest.raises(UnknownMotorError, match="commands motor 2"):
        p.decode(2, reply_of_1)
    batch = frames_of([CanFrame(0, reply_of_1), CanFrame(1, reply_of_1), CanFrame(2, reply_of_1)])
    assert verdicts_on_every_path(p, batch) == [[REPLY, REPLY, UNKNOWN]] * 4


def accepted_keys(p: MitProtocol) -> int:
    """How many byte-0 values of an 8-byte frame name a motor of ``p`` (its reply keys)."""
    return sum(1 for key in p._lut if key >> 8 == 8)


def test_random_foreign_frames_pass_only_as_often_as_the_reply_keys_allow(g1, rng):
    """Without a host id, a uniformly random 8-byte standard frame passes for a reply exactly when
    its byte 0 is a reply key of the bus (Damiao: 9 defined states x the id's nibble), its id is not
    another motor's, and a CubeMars error byte is defined. With the bus's host id, none passes
    unless it carries that id."""
    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    shipped = [b.make_protocol() for b in plan.buses]
    assert {p.host_id for p in shipped} == {0}  # the G1 plan names the motors' master id
    protocols = [MitProtocol(p.motors) for p in shipped]  # the same buses without it
    m = 200_000
    batch = frames(rng.integers(0, 0x800, m), rng.integers(0, 256, (m, 8)), 8)
    bus = rng.integers(0, len(protocols), m)
    accepted = MultiBusCodec(protocols).decode_replies(bus, batch).valid
    expected = 0.0
    for p in protocols:  # the probability of each key, times that of the other checks passing
        for mc in p.motors:
            keys = 9 if mc.reply == "damiao" else 1
            error_ok = len(CUBEMARS_ERRORS) / 256 if mc.reply == "cubemars" else 1.0
            id_ok = 1 - (len(p.motors) - 1) / 2048
            expected += keys / 256 * error_ok * id_ok / len(protocols)
    sigma = np.sqrt(expected * (1 - expected) / m)
    assert abs(accepted.mean() - expected) < 5 * sigma, (accepted.mean(), expected)
    assert expected < 0.08  # was 0.124 with every Damiao state nibble and any CubeMars error byte

    hosted = MultiBusCodec([MitProtocol(p.motors, host_id=0x10) for p in protocols]).decode_replies(bus, batch)
    assert set((batch["can_id"][hosted.valid] & 0x7FF).tolist()) <= {0x10}
    assert hosted.valid.sum() < accepted.sum() / 100
    as_shipped = MultiBusCodec(shipped).decode_replies(bus, batch)
    assert set((batch["can_id"][as_shipped.valid] & 0x7FF).tolist()) <= {0}
    assert as_shipped.valid.sum() < accepted.sum() / 100


# ----------------------------------------------------------------------------- commands
def test_commands_must_be_real_numbers():
    p = mixed_bus()
    for bad in ("1.0", None, True, [1.0], b"\x01", 1 + 2j):
        with pytest.raises(CommandValueError, match="real number"):
            p.encode_command(1, bad, 0.0, 0.0, 0.0, 0.0)
        if not isinstance(bad, list):  # a list is an array (broadcast to every motor)
            with pytest.raises(CommandValueError):
                p.encode_commands(0.0, 0.0, bad, 0.0, 0.0)
    assert p.encode_command(1, np.float32(1.0), np.int64(0), 0, 0.0, 0.0).frame.data == p.encode_command(1, 1.0, 0.0, 0.0, 0.0, 0.0).frame.data
    with pytest.raises(CommandValueError):
        p.encode_commands(np.array(["1.0"] * 5), 0.0, 0.0, 0.0, 0.0)


def test_a_number_beyond_any_float_is_the_codecs_error():
    p = mixed_bus()
    for huge in (10**400, -(10**400)):
        with pytest.raises(CommandValueError, match="beyond any float"):
            p.encode_command(1, huge, 0.0, 0.0, 0.0, 0.0)
        with pytest.raises(CommandValueError):
            p.encode_commands(0.0, huge, 0.0, 0.0, 0.0)
        with pytest.raises(CommandValueError):
            p.encode_commands([0.0, 0.0, 0.0, huge, 0.0], 0.0, 0.0, 0.0, 0.0)
    # infinities are numbers: clamped to the range ends, as any out-of-range value
    enc = p.encode_command(1, float("inf"), float("-inf"), 0.0, 0.0, 0.0)
    assert enc.clamped[:2] == (True, True) and enc.frame.data[:2] == b"\xff\xff"


def test_more_than_255_motors_across_buses():
    """Ids are per bus: 4 buses of 100 CubeMars motors (ids 1..100 each) are 400 valid motors."""
    protocols = [MitProtocol([motor(i, "cubemars", f"b{b}m{i}") for i in range(1, 101)]) for b in range(4)]
    codec = MultiBusCodec(protocols)
    rng = np.random.default_rng(7)
    values = [rng.uniform(-20, 20, 400), rng.uniform(-80, 80, 400), rng.uniform(0, 600, 400), rng.uniform(0, 6, 400), rng.uniform(-20, 20, 400)]
    batch, clamped = codec.encode_commands(*values)
    per_bus = [p.encode_commands(*(v[100 * b : 100 * (b + 1)] for v in values)) for b, p in enumerate(protocols)]
    assert batch["data"].tobytes() == b"".join(c.data.tobytes() for c in per_bus)
    assert np.array_equal(clamped, np.vstack([c.clamped for c in per_bus]))
    assert batch["can_id"].tolist() == list(range(1, 101)) * 4
    replies = frames_of([p.encode_reply(i, 0.1 * b, 0.0, 0.0) for b, p in enumerate(protocols) for i in range(1, 101)])
    decoded = codec.decode_replies(np.repeat(np.arange(4), 100), replies)
    assert decoded.valid.all() and decoded.index.tolist() == list(range(400))


# ----------------------------------------------------------------------------- fuzz
def oracle(p: MitProtocol, can_id: int, length: int, data: bytes) -> tuple[int, int]:
    """What a reply is, written out from the module's rules independently of the decoder:
    (verdict, motor index or -1)."""
    if can_id & CAN_ERR_FLAG:
        return ERROR_FRAME, -1
    if can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG):
        return UNKNOWN, -1
    if can_id > 0x7FF:
        return CORRUPT, -1  # junk in bits 11..28
    if p.host_id is not None and can_id != p.host_id:
        return UNKNOWN, -1
    if length == 0:
        return UNKNOWN, -1
    b0 = data[0]
    owner, same_byte = -1, False
    for i, m in enumerate(p.motors):
        var = REPLY_VARIANTS[m.reply]
        if var.name == "damiao":
            names = (b0 & 0x0F) == (m.can_id & 0x0F) and (b0 >> 4) in DAMIAO_STATES
        else:
            names = b0 == m.can_id
        same_byte |= names
        if names and length == var.length:
            owner = i
    if owner < 0:
        return (CORRUPT if same_byte else UNKNOWN), -1
    if any(m.can_id == can_id for j, m in enumerate(p.motors) if j != owner):
        return UNKNOWN, -1
    if length == 8 and data[:7] == b"\xff" * 7 and data[7] in (0xFB, 0xFC, 0xFD, 0xFE):
        return CORRUPT, -1
    if p.motors[owner].reply == "cubemars" and data[7] not in CUBEMARS_ERRORS:
        return CORRUPT, -1
    return REPLY, owner


def fuzz_frames(protocols: list[MitProtocol], rng: np.random.Generator, m: int) -> tuple[np.ndarray, np.ndarray]:
    """``m`` records on random buses: real replies, replies with mutated bytes / lengths / ids /
    flags, special frames, and uniform garbage."""
    bus = rng.integers(0, len(protocols), m)
    batch = np.zeros(m, dtype=FRAME)
    batch["data"] = rng.integers(0, 256, (m, 8))
    batch["len"] = rng.choice([0, 1, 5, 6, 7, 8, 8, 8, 9, 15, 64], m)
    batch["can_id"] = rng.choice([0, 0, 0, 1, 2, 3, 4, 5, 0x21, 0x80, 0x7FF], m)
    kind = rng.integers(0, 6, m)
    for k in np.flatnonzero(kind <= 2):  # a real reply of a motor of the bus (then maybe mutated)
        p = protocols[bus[k]]
        mc = p.motors[rng.integers(len(p.motors))]
        f = p.encode_reply(mc.can_id, *rng.uniform(-20, 20, 3), error_code=int(rng.integers(0, 9)), status=int(rng.integers(0, 16)),
                           temperature=float(rng.uniform(-50, 250)), arbitration_id=int(rng.choice([0, 0, mc.can_id, 0x10])))  # fmt: skip
        batch[k]["data"][: len(f.data)] = np.frombuffer(f.data, dtype=np.uint8)
        batch[k]["len"] = len(f.data) if kind[k] < 2 else rng.integers(0, 10)
        batch[k]["can_id"] = f.arbitration_id
    flips = kind == 1  # one random byte changed
    batch["data"][flips, rng.integers(0, 8, m)[flips]] = rng.integers(0, 256, int(flips.sum()))
    special = kind == 3
    batch["data"][special, :7] = 0xFF
    batch["data"][special, 7] = rng.integers(0xF9, 0x100, int(special.sum()))
    batch["data"][special, 0] = np.where(rng.random(int(special.sum())) < 0.5, 0xFF, batch["data"][special, 0])
    odd = rng.random(m)
    batch["can_id"][odd < 0.04] |= rng.integers(1, 1 << 18, int((odd < 0.04).sum()), dtype=np.uint32) << np.uint32(11)  # junk
    batch["can_id"][(odd >= 0.04) & (odd < 0.08)] |= np.uint32(CAN_EFF_FLAG)
    batch["can_id"][(odd >= 0.08) & (odd < 0.10)] |= np.uint32(CAN_RTR_FLAG)
    batch["can_id"][(odd >= 0.10) & (odd < 0.12)] |= np.uint32(CAN_ERR_FLAG)
    return batch, bus


def test_fuzz_every_decode_path_agrees_with_the_oracle(rng):
    """120k seeded frames over three buses (every reply variant, motor 0xFF, a host id on one bus):
    the scalar decoder, decode_frames, MitReplyDecoder and MultiBusCodec never raise, give the
    same verdict, motor and values for every frame, and accept exactly what the oracle calls a
    reply, with values inside the motor's ranges."""
    protocols = [
        mixed_bus(),
        MitProtocol([motor(3, "damiao"), motor(0x13, "original"), motor(0xFF, "cubemars")]),
        MitProtocol([motor(1, "cubemars"), motor(2, "damiao")], host_id=0x10),
    ]
    m = 120_000
    batch, bus = fuzz_frames(protocols, rng, m)
    first = np.cumsum([0] + [len(p.motors) for p in protocols])
    multi = MultiBusCodec(protocols).decode_replies(bus, batch)
    joint = MitReplyDecoder(protocols).decode(bus, batch)
    assert multi.verdict.tolist() == joint.verdict.tolist()
    for b, p in enumerate(protocols):
        rows = np.flatnonzero(bus == b)
        part = batch[rows]
        scalar = ActuatorProtocol.decode_frames(p, part)  # one decode() per frame: the scalar decoder
        fast = p.decode_frames(part)
        expected = [oracle(p, int(r["can_id"]), int(r["len"]), r["data"].tobytes()) for r in part]
        assert scalar.verdict.tolist() == [v for v, _ in expected]
        assert scalar.index.tolist() == [i for _, i in expected]
        offset = [i + first[b] if i >= 0 else -1 for i in scalar.index.tolist()]
        for other, index in ((fast, scalar.index.tolist()), (multi.take(rows), offset), (joint.take(rows), offset)):
            assert other.verdict.tolist() == scalar.verdict.tolist()
            assert other.index.tolist() == index
            ok = scalar.valid
            assert np.array_equal(other.state[ok], scalar.state[ok])
            for name in ("temperature", "rotor_temperature", "voltage"):
                assert np.array_equal(getattr(other, name)[ok], getattr(scalar, name)[ok], equal_nan=True)
            assert np.array_equal(other.error_code[ok], scalar.error_code[ok]) and np.array_equal(other.status[ok], scalar.status[ok])
        lo = np.array([[mc.model.position.min, mc.model.velocity.min, mc.model.torque.min] for mc in p.motors])
        hi = np.array([[mc.model.position.max, mc.model.velocity.max, mc.model.torque.max] for mc in p.motors])
        i = scalar.index[scalar.valid]
        assert ((scalar.state[scalar.valid] >= lo[i]) & (scalar.state[scalar.valid] <= hi[i])).all()
        counts = np.bincount(scalar.verdict, minlength=4)
        assert counts.min() > 100, counts  # every verdict well exercised


def test_a_plan_gives_its_buses_a_host_id():
    """``host_id`` in hardware.toml reaches the bus's protocol (and is validated)."""
    from giwbc.hal.hardware import HardwareConfigError, parse_hardware

    text = """
[[buses]]
name = "can0"
interface = "virtual"
channel = "x"
bitrate = 1000000
host_id = {host}

[[motors]]
bus = "can0"
id = 1
joint = "j1"
model = "DM4310"

[imu]
source = "emulated"
"""
    p = parse_hardware(text.format(host=0x10)).buses[0].make_protocol()
    assert p.host_id == 0x10
    reply = p.encode_reply(1, 0.0, 0.0, 0.0)
    assert reply.arbitration_id == 0x10 and p.decode(0x10, reply.data).motor_id == 1
    with pytest.raises(UnknownMotorError):
        p.decode(0, reply.data)
    for bad in ("0x800", "-1", '"0"'):
        with pytest.raises(HardwareConfigError, match="host_id"):
            parse_hardware(text.format(host=bad))


def test_a_repeated_steady_batch_decodes_as_a_fresh_decoder_does(g1, rng):
    """The G1's buses, every motor replying once per cycle in plan order with new values: the
    decoder that keeps the last steady batch's lookup gives, batch after batch, exactly what a
    fresh decoder gives; a batch whose ids or byte 0 change (a frame from no motor, a motor
    missing) is decoded afresh, and the steady batches after it again agree."""
    plan = load_hardware(g1.folder / "hardware.toml", 500.0, joint_names=g1.joint_names, interface="virtual")
    protocols = [b.make_protocol() for b in plan.buses]
    kept = MitReplyDecoder(protocols)

    def cycle() -> tuple[np.ndarray, np.ndarray]:
        replies, bus = [], []
        for b, p in enumerate(protocols):
            for mc in p.motors:
                span = np.array([[mc.model.position.min, mc.model.position.max], [mc.model.velocity.min, mc.model.velocity.max],
                                 [mc.model.torque.min, mc.model.torque.max]])  # fmt: skip
                q, v, tau = rng.uniform(span[:, 0], span[:, 1])
                replies.append(p.encode_reply(mc.can_id, q, v, tau, temperature=float(rng.uniform(20, 80))))
                bus.append(b)
        return frames_of(replies), np.array(bus)

    def agree(batch: np.ndarray, bus: np.ndarray) -> np.ndarray:
        got, fresh = kept.decode(bus, batch), MitReplyDecoder(protocols).decode(bus, batch)
        for name in ("verdict", "index", "motor_id", "state", "temperature", "rotor_temperature", "error_code", "voltage", "status"):
            assert np.array_equal(getattr(got, name), getattr(fresh, name), equal_nan=True), name
        return got.verdict

    for _ in range(3):
        assert (agree(*cycle()) == REPLY).all()
    batch, bus = cycle()
    stray = batch.copy()
    stray["can_id"][4] = 0x123  # not the host id: foreign traffic
    assert agree(stray, bus)[4] != REPLY
    assert (agree(batch, bus) == REPLY).all()
    cubemars = [i for i, mc in enumerate(mc for p in protocols for mc in p.motors) if mc.reply == "cubemars"]
    assert cubemars  # the G1 plan has CubeMars motors: their error byte is checked on every batch
    undefined = batch.copy()
    undefined["data"][cubemars[0], 7] = 0xFF  # no CubeMars error code: corrupt
    assert agree(undefined, bus)[cubemars[0]] != REPLY
    assert (agree(batch[1:], bus[1:]) == REPLY).all()  # a motor missing: a shorter batch
    assert (agree(*cycle()) == REPLY).all()
