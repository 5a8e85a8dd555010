"""MIT mode ("mini-cheetah" protocol): 8-byte impedance commands, fixed-point replies.

Command frame, standard 11-bit id = the motor's CAN id, big-endian bit fields::

    position 16 | velocity 12 | kp 12 | kd 12 | torque 12        (64 bits)

Each value is clamped on the host to its motor-side range, then quantized to the nearest code,
``u = round((x - min) * (2**bits - 1) / (max - min))``, exact ties going to the lower code (so 0 in
a symmetric range is the well-known ``0x7FFF`` / ``0x7FF``, as the reference firmware's truncating
conversion gives). Decoding is ``x = u * (max - min) / (2**bits - 1) + min``; a round trip is
within half a code step.

Special frames (same id): enter motor mode ``FF FF FF FF FF FF FF FC``, exit ``..FD``, set zero
``..FE`` (Damiao: clear errors ``..FB``).

Reply variants, all sharing ``p16 | v12 | t12`` in bytes 1..5 and demultiplexed by byte 0
(the arbitration id of replies is the firmware's master id and is not used, unless ``host_id`` is
given):

==========  =====  ======================================================================
variant     bytes  layout
==========  =====  ======================================================================
original    6      id, p16, v12, t12 (Ben Katz firmware)
voltage     7      original + byte 6 = bus voltage. ASSUMPTION: unsigned, ``voltage_lsb``
                   volts per count (default 0.25 V: 0..63.75 V covers 24 V and 48 V packs);
                   no vendor standard exists for this trailing byte, set it per firmware.
cubemars    8      original + byte 6 = temperature, °C + 40 (-40..215 °C, see below) + byte 7
                   = error code, 0..7 (``CUBEMARS_ERRORS``; another value: corrupt)
damiao      8      byte 0 = state << 4 | (id & 0x0F), p16, v12, t12, MOS temperature °C,
                   rotor temperature °C. States are ``DAMIAO_STATES`` (0, 1, 8..14);
                   ``error_code`` = state if state >= 8 else 0. Byte 0 with an undefined
                   state (2..7, 15) names no motor: the frame is not a reply (unknown).
==========  =====  ======================================================================

The variant is a property of the motor (``MotorConfig.reply``); two motors whose replies could be
confused (same length and byte 0) are refused when the protocol is built.

What a reply is (the same rules in :meth:`MitProtocol.decode` and :class:`MitReplyDecoder`):

- a standard data frame (extended, remote and error frames are not replies), with an 11-bit id
  (a record with junk in id bits 11..28 is corrupt), equal to ``host_id`` when one is given;
- ``(length, byte 0)`` is one motor's key: its variant's length and its id (Damiao: a defined
  state and the id's low nibble). No payload at all (a CANopen SYNC) or a byte 0 that names no
  motor is *unknown* (foreign traffic, counted); a motor's byte 0 with another length is *corrupt*;
- the arbitration id is not the command id of *another* motor of the bus: a node whose replies
  carried motor j's id would command motor j, so such a frame is traffic for j (unknown). (CubeMars
  firmware replies with its own id, "0x00 + driver ID", which stays allowed);
- not a special command frame (``FF .. FF FB..FE``), and a CubeMars error byte is a defined code.

CubeMars temperature: T-Motor support told a host-library author to subtract 40 from byte 6
(neurobionics/TMotorCANControl pull request 4), which is what this module does; the AK manual
V1.0.8 (MIT mode reply table) names byte 6 "motor temperature" without a scale, that library and
the same author's AK60-6 V1.1 firmware read it raw (room temperature came out right without the
offset), while other public hosts subtract 40. It depends on the firmware: verify on the drive
(read it at a known temperature) before trusting over-temperature margins.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from giwbc.hal.kernels import steady_key, steady_replies, warm_up
from giwbc.hal.motor import RANGE_FIELDS, MotorConfig
from giwbc.hal.protocols.base import (
    ActuatorProtocol,
    CanFrame,
    CanProtocolError,
    CommandBatch,
    CommandValueError,
    CORRUPT,
    ERROR_FRAME,
    REPLY,
    UNKNOWN,
    CorruptFrameError,
    DecodedReplies,
    EncodedCommand,
    FrameLengthError,
    FrameTraffic,
    MotorCommand,
    MotorReply,
    ProtocolConfigError,
    UnknownMotorError,
)

COMMAND_BITS: tuple[int, ...] = (16, 12, 12, 12, 12)
COMMAND_LEVELS: tuple[int, ...] = tuple((1 << b) - 1 for b in COMMAND_BITS)
_SHIFTS = (48, 36, 24, 12, 0)
_LEVELS_F = np.array(COMMAND_LEVELS, dtype=float)
_SHIFTS_U = np.array(_SHIFTS, dtype=np.uint64)
_FIELD_UNITS = np.uint64(1) << _SHIFTS_U  # each field's lowest bit in the 64-bit word
_P_LEVELS, _VT_LEVELS = 65535, 4095

ENTER_MOTOR_MODE = b"\xff" * 7 + b"\xfc"
EXIT_MOTOR_MODE = b"\xff" * 7 + b"\xfd"
SET_ZERO = b"\xff" * 7 + b"\xfe"
CLEAR_ERRORS = b"\xff" * 7 + b"\xfb"  # Damiao
_SPECIAL_LAST = frozenset({0xFB, 0xFC, 0xFD, 0xFE})
_SPECIAL_NAMES = MappingProxyType({0xFC: "enter", 0xFD: "exit", 0xFE: "zero", 0xFB: "clear"})

CUBEMARS_TEMPERATURE_OFFSET = -40.0  # °C = byte + offset (firmware dependent: see the module docstring)
DEFAULT_VOLTAGE_LSB = 0.25  # V per count of the 7-byte variant's trailing byte (assumption, see module doc)
MAX_STANDARD_ID = 0x7FF


@dataclass(frozen=True, slots=True)
class ReplyVariant:
    """A reply layout: payload length and how many bits of byte 0 carry the motor id."""

    name: str
    length: int
    id_bits: int
    code: int


REPLY_VARIANTS: Mapping[str, ReplyVariant] = MappingProxyType(
    {
        "original": ReplyVariant("original", 6, 8, 0),
        "voltage": ReplyVariant("voltage", 7, 8, 1),
        "cubemars": ReplyVariant("cubemars", 8, 8, 2),
        "damiao": ReplyVariant("damiao", 8, 4, 3),
    }
)
_ORIGINAL, _VOLTAGE, _CUBEMARS, _DAMIAO = 0, 1, 2, 3

CUBEMARS_ERRORS: Mapping[int, str] = MappingProxyType(
    {
        0: "no fault",
        1: "motor over-temperature",
        2: "over-current",
        3: "over-voltage",
        4: "under-voltage",
        5: "encoder fault",
        6: "MOSFET over-temperature",
        7: "motor stall",
    }
)
DAMIAO_STATES: Mapping[int, str] = MappingProxyType(
    {
        0x0: "disabled",
        0x1: "enabled",
        0x8: "over-voltage",
        0x9: "under-voltage",
        0xA: "over-current",
        0xB: "MOS over-temperature",
        0xC: "rotor over-temperature",
        0xD: "communication lost",
        0xE: "overload",
    }
)
CUBEMARS_MAX_ERROR = max(CUBEMARS_ERRORS)


def _code(x: float, lo: float, hi: float, span: float, levels: int) -> tuple[int, bool]:
    """Clamp then quantize one value; (code, clamped). NaN raises CommandValueError."""
    if x != x:
        raise CommandValueError("NaN cannot be encoded")
    if x < lo:
        return 0, True
    if x > hi:
        return levels, True
    return math.ceil((x - lo) * levels / span - 0.5), False


def _bounds(motor: MotorConfig) -> tuple[tuple[float, float, float, int], ...]:
    return tuple((r.min, r.max, r.span, lv) for r, lv in zip(motor.model.ranges, COMMAND_LEVELS))


def pack_command(
    motor: MotorConfig, position: float, velocity: float, kp: float, kd: float, torque: float
) -> tuple[bytes, tuple[bool, bool, bool, bool, bool]]:
    """The 8 data bytes of one MIT command (motor-side values) and the per-field clamp mask."""
    return _pack(_bounds(motor), (position, velocity, kp, kd, torque))


def _real(name: str, x: Any) -> float:
    """``x`` as a float if it is a real number (int, float, numpy scalar; not bool, str, ...)."""
    if type(x) is float:
        return x
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise CommandValueError(f"command field {name} must be a real number, got {type(x).__name__} {x!r}")
    try:
        return float(x)
    except OverflowError:
        raise CommandValueError(f"command field {name} = {x} is beyond any float (clamping needs a number)") from None


def _pack(bounds: tuple[tuple[float, float, float, int], ...], values: tuple[float, ...]) -> tuple[bytes, Any]:
    word = 0
    clamped = []
    for (lo, hi, span, levels), shift, x, name in zip(bounds, _SHIFTS, values, RANGE_FIELDS):
        x = _real(name, x)
        if lo <= x <= hi:
            word |= math.ceil((x - lo) * levels / span - 0.5) << shift
            clamped.append(False)
        elif x > hi:
            word |= levels << shift
            clamped.append(True)
        elif x < lo:
            clamped.append(True)
        else:
            raise CommandValueError(f"NaN in command fields {dict(zip(RANGE_FIELDS, values))}")
    return word.to_bytes(8, "big"), tuple(clamped)


class MitCommandEncoder:
    """MIT command payloads of a list of motors (any number, any ids: payloads do not contain the
    id), vectorized: the arithmetic of :func:`pack_command`, row by row."""

    def __init__(self, motors: Sequence[MotorConfig]) -> None:
        n = self.n = len(motors)
        self.names = tuple(m.joint for m in motors)
        self._lo = np.array([[r.min for r in m.model.ranges] for m in motors], dtype=float).reshape(n, 5)
        self._hi = np.array([[r.max for r in m.model.ranges] for m in motors], dtype=float).reshape(n, 5)
        self._span = self._hi - self._lo
        self._lo_rows, self._hi_rows, self._span_rows = (np.ascontiguousarray(a.T) for a in (self._lo, self._hi, self._span))
        self._levels_rows = _LEVELS_F[:, None]

    def encode(self, *fields: ArrayLike) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
        """Payloads ``(N, 8)`` and the clamp mask ``(N, 5)`` from position, velocity, kp, kd and
        torque (arrays in motor order or scalars). Non-numbers and NaN raise CommandValueError."""
        n = self.n
        x = np.empty((n, 5), dtype=float)
        for j, (name, v) in enumerate(zip(RANGE_FIELDS, fields)):
            if not (type(v) is np.ndarray and v.dtype.kind == "f"):
                v = _real_array(name, v)
            x[:, j] = v
        nan = np.isnan(x)
        if nan.any():
            bad = [f"{self.names[i]}.{RANGE_FIELDS[j]}" for i, j in zip(*np.nonzero(nan))]
            raise CommandValueError(f"NaN in commands: {', '.join(bad)}")
        clamped = (x < self._lo) | (x > self._hi)
        np.minimum(np.maximum(x, self._lo, out=x), self._hi, out=x)  # np.clip (no NaN here), without its wrapper
        x -= self._lo
        x *= _LEVELS_F
        x /= self._span
        x -= 0.5
        np.ceil(x, out=x)
        words = x.astype(np.uint64) @ _FIELD_UNITS  # the fields' bits do not overlap: their sum is their OR
        return words.astype(">u8").view(np.uint8).reshape(n, 8), clamped

    def encode_rows(self, rows: NDArray[np.float64]) -> tuple[NDArray[np.uint64], NDArray[np.bool_]]:
        """:meth:`encode` of a ``(5, N)`` float block (rows position, velocity, kp, kd, torque,
        motor order; overwritten): the payloads as big-endian 64-bit words, and the clamp mask
        ``(N, 5)``. The same arithmetic, element by element, in fewer calls (the control loop's
        form); NaN raises CommandValueError naming the fields."""
        if np.count_nonzero(np.isnan(rows)):
            self.encode(*rows)  # raises, naming the joints and fields
        lo, hi = self._lo_rows, self._hi_rows
        clamped = (rows < lo) | (rows > hi)
        np.minimum(np.maximum(rows, lo, out=rows), hi, out=rows)
        rows -= lo
        rows *= self._levels_rows
        rows /= self._span_rows
        rows -= 0.5
        np.ceil(rows, out=rows)
        return _FIELD_UNITS @ rows.astype(np.uint64), clamped.T


def _real_array(name: str, v: Any) -> NDArray[np.float64]:
    """``v`` (a scalar or array of real numbers) as floats; CommandValueError otherwise."""
    try:
        a = np.asarray(v)
    except (OverflowError, ValueError, TypeError) as e:
        raise CommandValueError(f"command field {name}: not an array of real numbers ({e})") from None
    if a.dtype.kind not in "fiu":
        if a.dtype.kind == "O" and all(not isinstance(x, (bool, np.bool_)) and isinstance(x, (int, float, np.integer, np.floating)) for x in a.flat):
            try:
                return a.astype(float)
            except OverflowError:
                raise CommandValueError(f"command field {name}: a value is beyond any float") from None
        raise CommandValueError(f"command field {name} must be real numbers, got {a.dtype} {v!r}")
    return a.astype(float, copy=False)


class MitProtocol(ActuatorProtocol):
    """MIT mode for the motors of one bus.

    ``host_id``: when given, only frames with this arbitration id are accepted as replies (the
    firmware's master id); by default replies are recognised by length and byte 0 alone.
    """

    name = "mit"
    reply_variants = tuple(REPLY_VARIANTS)

    def __init__(
        self, motors: Sequence[MotorConfig], *, host_id: int | None = None, voltage_lsb: float = DEFAULT_VOLTAGE_LSB
    ) -> None:
        super().__init__(motors)
        if host_id is not None and not 0 <= host_id <= MAX_STANDARD_ID:
            raise ProtocolConfigError(f"host_id must be a standard 11-bit id, got {host_id}")
        if not (math.isfinite(voltage_lsb) and voltage_lsb > 0):
            raise ProtocolConfigError(f"voltage_lsb must be > 0, got {voltage_lsb}")
        self.host_id = host_id
        self.voltage_lsb = float(voltage_lsb)
        self._variants: tuple[ReplyVariant, ...] = tuple(self._variant(m) for m in self.motors)
        self._bounds = [_bounds(m) for m in self.motors]
        # Demultiplexing table: key (length << 8 | byte 0) -> motor index; byte 0 -> a motor using it.
        self._lut: dict[int, int] = {}
        self._by_byte0: dict[int, int] = {}
        for i, (m, var) in enumerate(zip(self.motors, self._variants)):
            if not 0 <= m.can_id <= MAX_STANDARD_ID:
                raise ProtocolConfigError(f"motor {m.joint!r}: MIT mode uses 11-bit ids, got 0x{m.can_id:X}")
            if var.id_bits == 8:
                if m.can_id > 0xFF:
                    raise ProtocolConfigError(
                        f"motor {m.joint!r}: id 0x{m.can_id:X} does not fit byte 0 of a {var.name!r} reply (max 0xFF)"
                    )
                keys = [m.can_id]
            else:
                keys = [(s << 4) | (m.can_id & 0x0F) for s in DAMIAO_STATES]
            for b0 in keys:
                key = (var.length << 8) | b0
                other = self._lut.get(key)
                if other is not None:
                    o = self.motors[other]
                    raise ProtocolConfigError(
                        f"replies of motor {m.joint!r} (id {m.can_id}, {var.name}) and motor {o.joint!r} "
                        f"(id {o.can_id}, {self._variants[other].name}) cannot be told apart "
                        f"({var.length} bytes, byte 0 = 0x{b0:02X})"
                    )
                self._lut[key] = i
                self._by_byte0.setdefault(b0, i)
        # Per-motor decode scales (u * scale + lo, same expression in scalar and vector paths).
        self._dec = [
            (m.model.position.min, m.model.position.span / _P_LEVELS,
             m.model.velocity.min, m.model.velocity.span / _VT_LEVELS,
             m.model.torque.min, m.model.torque.span / _VT_LEVELS)
            for m in self.motors
        ]  # fmt: skip
        self._arb_ids = np.array([m.can_id for m in self.motors], dtype=np.int64)
        self._encoder = MitCommandEncoder(self.motors)
        self._decoder: MitReplyDecoder | None = None

    @staticmethod
    def _variant(motor: MotorConfig) -> ReplyVariant:
        try:
            return REPLY_VARIANTS[motor.reply]  # type: ignore[index]
        except KeyError:
            raise ProtocolConfigError(
                f"motor {motor.joint!r}: unknown MIT reply variant {motor.reply!r}; known: {', '.join(REPLY_VARIANTS)}"
            ) from None

    @classmethod
    def traffic(cls, motor: MotorConfig) -> FrameTraffic:
        return FrameTraffic(8, cls._variant(motor).length)

    # ---------------------------------------------------------------- commands
    def encode_command(
        self, motor_id: int, position: float, velocity: float, kp: float, kd: float, torque: float
    ) -> EncodedCommand:
        i = self.index.get(motor_id)
        if i is None:
            raise UnknownMotorError(f"no motor with id {motor_id} on this bus")
        data, clamped = _pack(self._bounds[i], (position, velocity, kp, kd, torque))
        return EncodedCommand(CanFrame(motor_id, data), clamped)

    def encode_commands(
        self, position: ArrayLike, velocity: ArrayLike, kp: ArrayLike, kd: ArrayLike, torque: ArrayLike
    ) -> CommandBatch:
        data, clamped = self._encoder.encode(position, velocity, kp, kd, torque)
        return CommandBatch(self._arb_ids, data, clamped)

    def _special(self, motor_id: int, payload: bytes) -> CanFrame:
        if motor_id not in self.index:
            raise UnknownMotorError(f"no motor with id {motor_id} on this bus")
        return CanFrame(motor_id, payload)

    def enter_motor_mode(self, motor_id: int) -> CanFrame:
        return self._special(motor_id, ENTER_MOTOR_MODE)

    def exit_motor_mode(self, motor_id: int) -> CanFrame:
        return self._special(motor_id, EXIT_MOTOR_MODE)

    def set_zero(self, motor_id: int) -> CanFrame:
        return self._special(motor_id, SET_ZERO)

    def clear_errors(self, motor_id: int) -> CanFrame:
        """Damiao firmware only: clear a latched fault."""
        return self._special(motor_id, CLEAR_ERRORS)

    # ----------------------------------------------------------------- replies
    def decode(self, arbitration_id: Any, data: Any, is_extended_id: bool = False) -> MotorReply:
        try:
            return self._decode(arbitration_id, data, is_extended_id)
        except CanProtocolError:
            raise
        except Exception as e:  # defensive: totality, whatever the input type
            raise CorruptFrameError(f"undecodable input: {type(e).__name__}: {e}") from e

    def _decode(self, arbitration_id: Any, data: Any, is_extended_id: bool) -> MotorReply:
        data = _as_bytes(data)
        ext = bool(is_extended_id)
        if type(arbitration_id) is not int:
            if isinstance(arbitration_id, bool) or not isinstance(arbitration_id, (int, np.integer)):
                raise CorruptFrameError(f"arbitration id must be an integer, got {type(arbitration_id).__name__}")
            arbitration_id = int(arbitration_id)
        if not 0 <= arbitration_id <= (0x1FFFFFFF if ext else MAX_STANDARD_ID):
            raise CorruptFrameError(f"arbitration id 0x{arbitration_id:X} out of range")
        if ext:
            raise UnknownMotorError(f"extended frame 0x{arbitration_id:X} is not an MIT reply")
        if self.host_id is not None and arbitration_id != self.host_id:
            raise UnknownMotorError(f"frame id 0x{arbitration_id:X} is not the host id 0x{self.host_id:X}")
        n = len(data)
        if n == 0:
            raise UnknownMotorError("a frame without payload (a CANopen SYNC, ...) names no motor")
        b0 = data[0]
        i = self._lut.get((n << 8) | b0) if n <= 8 else None
        if i is None:
            j = self._by_byte0.get(b0)
            if j is not None:
                var = self._variants[j]
                raise FrameLengthError(
                    f"motor id {self.motors[j].can_id} replies with {var.length} bytes ({var.name}), got {n}"
                )
            raise UnknownMotorError(f"no motor on this bus replies with byte 0 = 0x{b0:02X} in {n} bytes")
        r = self.index.get(arbitration_id)
        if r is not None and r != i:
            raise UnknownMotorError(
                f"frame id 0x{arbitration_id:X} commands motor {arbitration_id}: not a reply of motor {self.motors[i].can_id}"
            )
        if n == 8 and data[7] in _SPECIAL_LAST and data[:7] == b"\xff" * 7:
            raise CorruptFrameError("a special command frame, not a reply")
        p_lo, p_sc, v_lo, v_sc, t_lo, t_sc = self._dec[i]
        d4 = data[4]
        position = ((data[1] << 8) | data[2]) * p_sc + p_lo
        velocity = ((data[3] << 4) | (d4 >> 4)) * v_sc + v_lo
        torque = (((d4 & 0x0F) << 8) | data[5]) * t_sc + t_lo
        motor_id = self.motors[i].can_id
        code = self._variants[i].code
        if code == _ORIGINAL:
            return MotorReply(motor_id, position, velocity, torque)
        if code == _VOLTAGE:
            return MotorReply(motor_id, position, velocity, torque, voltage=data[6] * self.voltage_lsb)
        if code == _CUBEMARS:
            if data[7] > CUBEMARS_MAX_ERROR:
                raise CorruptFrameError(f"CubeMars error byte {data[7]} is no defined error code (0..{CUBEMARS_MAX_ERROR})")
            return MotorReply(
                motor_id, position, velocity, torque,
                temperature=data[6] + CUBEMARS_TEMPERATURE_OFFSET, error_code=data[7],
            )  # fmt: skip
        state = b0 >> 4
        return MotorReply(
            motor_id, position, velocity, torque,
            temperature=float(data[6]), rotor_temperature=float(data[7]),
            error_code=state if state >= 8 else 0, status=state,
        )  # fmt: skip

    def decode_frames(self, batch: NDArray[Any]) -> DecodedReplies:
        """Vectorized :meth:`ActuatorProtocol.decode_frames` (same results as :meth:`decode` per frame)."""
        if self._decoder is None:
            self._decoder = MitReplyDecoder([self])
        return self._decoder.decode(np.zeros(len(batch), dtype=np.int64), batch)

    def decode_command(self, arbitration_id: Any, data: Any, is_extended_id: bool = False) -> MotorCommand:
        try:
            return self._decode_command(arbitration_id, data, is_extended_id)
        except CanProtocolError:
            raise
        except Exception as e:  # defensive: totality, whatever the input type
            raise CorruptFrameError(f"undecodable input: {type(e).__name__}: {e}") from e

    def _decode_command(self, arbitration_id: Any, data: Any, is_extended_id: bool) -> MotorCommand:
        data = _as_bytes(data)
        if bool(is_extended_id):
            raise UnknownMotorError("extended frames are not MIT commands")
        i = self.index.get(arbitration_id) if type(arbitration_id) is int else None
        if i is None:
            raise UnknownMotorError(f"no motor with id {arbitration_id!r} on this bus")
        if len(data) != 8:
            raise FrameLengthError(f"MIT commands have 8 bytes, got {len(data)}")
        if data[7] in _SPECIAL_LAST and data[:7] == b"\xff" * 7:
            nan = math.nan
            return MotorCommand(arbitration_id, nan, nan, nan, nan, nan, _SPECIAL_NAMES[data[7]])
        word = int.from_bytes(data, "big")
        values = [
            ((word >> shift) & levels) * span / levels + lo
            for (lo, _, span, levels), shift in zip(self._bounds[i], _SHIFTS)
        ]
        return MotorCommand(arbitration_id, *values)

    def encode_reply(
        self,
        motor_id: int,
        position: float,
        velocity: float,
        torque: float,
        *,
        temperature: float = 25.0,
        rotor_temperature: float = 25.0,
        error_code: int = 0,
        voltage: float = 24.0,
        status: int | None = None,
        arbitration_id: int | None = None,
    ) -> CanFrame:
        """A reply in ``motor_id``'s variant; values are clamped to its ranges like firmware codes.

        Damiao: ``status`` defaults to ``error_code`` if non-zero, else 1 (enabled).
        """
        i = self.index.get(motor_id)
        if i is None:
            raise UnknownMotorError(f"no motor with id {motor_id} on this bus")
        bounds = self._bounds[i]
        try:
            p, _ = _code(float(position), *bounds[0])
            v, _ = _code(float(velocity), *bounds[1])
            t, _ = _code(float(torque), *bounds[4])
        except CommandValueError:
            raise CommandValueError(f"NaN in reply for motor {motor_id}") from None
        var = self._variants[i]
        if var.code == _DAMIAO:
            st = (error_code if error_code else 1) if status is None else status
            if not 0 <= st <= 15:
                raise ValueError(f"Damiao state must be 0..15, got {st}")
            b0 = (st << 4) | (motor_id & 0x0F)
        else:
            b0 = motor_id & 0xFF
        out = bytearray((b0, p >> 8, p & 0xFF, v >> 4, ((v & 0x0F) << 4) | (t >> 8), t & 0xFF))
        if var.code == _VOLTAGE:
            out.append(_byte(voltage / self.voltage_lsb))
        elif var.code == _CUBEMARS:
            if not 0 <= error_code <= 0xFF:
                raise ValueError(f"error code must be 0..255, got {error_code}")
            out += bytes((_byte(temperature - CUBEMARS_TEMPERATURE_OFFSET), error_code))
        elif var.code == _DAMIAO:
            out += bytes((_byte(temperature), _byte(rotor_temperature)))
        arb = arbitration_id if arbitration_id is not None else (self.host_id or 0)
        return CanFrame(arb, bytes(out))


class MitReplyDecoder:
    """Replies of the motors of one or several MIT buses, decoded in one vectorized call.

    Motors are numbered in bus order, then each bus's motor order (a robot's plan order), and each
    frame comes with the index of the bus it arrived on, so motors with the same id on different
    buses are told apart. Exactly the checks and arithmetic of :meth:`MitProtocol.decode` (the
    tests compare them frame by frame on random input): one table lookup per frame on (bus,
    length, byte 0) gives the motor or the reason it is none, one gather gives the motor's
    constants, and the bit fields come out of one exact integer product. The rarer checks (flags,
    junk id bits, host id, another motor's command id, special frames, CubeMars error codes) cost
    one test each when no frame needs them.
    """

    # Bit fields of the payload read as one big-endian 64-bit word: position (bytes 1-2), velocity
    # (byte 3 and the high nibble of byte 4), torque (low nibble of byte 4 and byte 5).
    _SHIFTS = np.array([40, 28, 16], dtype=np.uint64)
    _MASKS = np.array([0xFFFF, 0xFFF, 0xFFF], dtype=np.uint64)

    def __init__(self, protocols: Sequence[MitProtocol]) -> None:
        self.protocols = tuple(protocols)
        motors = [m for p in self.protocols for m in p.motors]
        n = self.n_motors = len(motors)
        buses = len(self.protocols)
        unknown, corrupt = n, n + 1
        first = np.cumsum([0] + [len(p.motors) for p in self.protocols])
        # lut[bus, min(length, 9), byte 0]: the global motor index, or n (unknown: no payload, or a
        # byte 0 no motor of the bus uses), or n + 1 (corrupt: the byte 0 of a motor of this bus
        # with a length it does not reply with, longer than 8 bytes included).
        lut = np.full((buses, 10, 256), unknown, dtype=np.int64)
        # reserved[bus, 11-bit id]: the global index of the motor whose command id it is, or -1.
        reserved = np.full((buses, MAX_STANDARD_ID + 1), -1, dtype=np.int64)
        for b, p in enumerate(self.protocols):
            lut[b, 1:, list(p._by_byte0)] = corrupt
            for key, i in p._lut.items():
                lut[b, key >> 8, key & 0xFF] = first[b] + i
            for i, m in enumerate(p.motors):
                reserved[b, m.can_id] = first[b] + i
        self._lut = lut.reshape(-1)
        self._reserved = reserved.reshape(-1)
        self._unknown, self._corrupt = unknown, corrupt
        self._host_id = np.array([-1 if p.host_id is None else p.host_id for p in self.protocols], dtype=np.int64)
        self._any_host_id = bool((self._host_id >= 0).any())
        # Per lookup result (motors, then unknown, corrupt): verdict, index, CAN id, and the constants:
        # position lo, scale, velocity lo, scale, torque lo, scale; temperature offset of byte 6 (NaN:
        # not reported); volts per count of byte 6 (NaN: none); rotor temperature offset of byte 7
        # (NaN: none); error code from byte 7 (1: CubeMars), from the state nibble (1: Damiao).
        nan = math.nan
        rows = []
        for p in self.protocols:
            for i, v in enumerate(p._variants):
                temperature = {_CUBEMARS: CUBEMARS_TEMPERATURE_OFFSET, _DAMIAO: 0.0}.get(v.code, nan)
                volts = p.voltage_lsb if v.code == _VOLTAGE else nan
                rotor = 0.0 if v.code == _DAMIAO else nan
                rows.append((*p._dec[i], temperature, volts, rotor, float(v.code == _CUBEMARS), float(v.code == _DAMIAO)))
        none = (*(nan,) * 9, 0.0, 0.0)
        self._table = np.array([*rows, none, none], dtype=float).reshape(n + 2, 11)
        self._verdict = np.array([REPLY] * n + [UNKNOWN, CORRUPT], dtype=np.int64)
        self._index = np.array([*range(n), -1, -1], dtype=np.int64)
        self._can_id = np.array([m.can_id for m in motors] + [-1, -1], dtype=np.int64)
        self._is_cubemars = self._table[:, 9] != 0
        self._has_cubemars = bool(self._is_cubemars.any())
        self._has_error_field = any(v.code in (_CUBEMARS, _DAMIAO) for p in self.protocols for v in p._variants)
        # The steady state repeats: each cycle the same motors reply on the same buses with the same
        # ids, lengths and byte 0. What follows from those alone (the lookup, the checks, the
        # constants) is kept from the last batch of all replies and reused while they repeat.
        self._steady: tuple[Any, ...] | None = None  # (the kernel's constants, then the fields handed out)
        warm_up()  # the steady decode's kernel compiled (or loaded) now, not in a first steady cycle

    def decode(self, bus: ArrayLike, batch: NDArray[Any]) -> DecodedReplies:
        """Decode ``batch`` (:data:`~giwbc.hal.frames.FRAME` records); ``bus[k]`` is the index (in
        this decoder's protocols) of the bus frame ``k`` arrived on."""
        m = len(batch)
        n = self.n_motors
        bus = np.asarray(bus, dtype=np.int64).reshape(m)
        steady = self._steady
        if steady is not None and batch.flags.c_contiguous and batch.dtype.itemsize == 16:
            # The key (ids, lengths, byte 0, buses) compared and the payloads decoded in one
            # compiled call over the frames' bytes (giwbc.hal.kernels).
            decoded = self._decode_steady(batch.view(np.uint8).reshape(m, 16), bus, *steady)
            if decoded is not None:
                return decoded
        word = batch["data"].view(">u8").reshape(m).astype(np.uint64)
        length = batch["len"]
        can_id = batch["can_id"]
        b0 = (word >> np.uint64(56)).astype(np.int64)
        k = self._lut[(bus * 10 + np.minimum(length, 9)) * 256 + b0]
        some_id = bool(can_id.any())  # replies to host id 0, the usual case, skip the id checks
        sid = can_id & MAX_STANDARD_ID if some_id or self._any_host_id else can_id
        if some_id:
            r = self._reserved[bus * (MAX_STANDARD_ID + 1) + sid]
            clash = (r >= 0) & (r != k) & (k < n)  # another motor's command id: traffic for it
            if clash.any():
                k = np.where(clash, self._unknown, k)
        maybe_special = (b0 == 0xFF) & (k < n)
        if maybe_special.any():  # 8 bytes FF .. FF FB..FE: a special command frame, no reply
            last = word & np.uint64(0xFF)
            special = maybe_special & (length == 8) & ((word >> np.uint64(8)) == np.uint64(0xFFFFFFFFFFFFFF)) & (last >= 0xFB) & (last <= 0xFE)
            k = np.where(special, self._corrupt, k)
        d7 = (word & np.uint64(0xFF)).astype(np.int64)
        if self._has_cubemars:
            undefined = d7 > CUBEMARS_MAX_ERROR
            if undefined.any():
                k = np.where(undefined & self._is_cubemars[k], self._corrupt, k)
        if self._any_host_id:
            host = self._host_id[bus]
            k = np.where((host >= 0) & (sid != host), self._unknown, k)
        any_high = False
        if some_id:
            high = can_id >> 11  # flags (EFF, RTR, ERR) and, in a standard frame, junk id bits
            flags = high >> 18
            any_high = bool(high.any())
            if any_high:
                k = np.where(flags != 0, self._unknown, np.where(high != 0, self._corrupt, k))
        verdict = self._verdict[k]
        if any_high:
            verdict[(flags & 1) != 0] = ERROR_FRAME
        t = self._table[k]
        values = ((word[:, None] >> self._SHIFTS) & self._MASKS) * t[:, 1:6:2] + t[:, 0:6:2]
        d6 = ((word >> np.uint64(8)) & np.uint64(0xFF)).astype(np.int64)
        if self._has_error_field:
            state = b0 >> 4
            damiao = t[:, 10] != 0
            error = np.where(t[:, 9] != 0, d7, np.where(damiao, np.where(state >= 8, state, 0), -1))
            status = np.where(damiao, state, -1)
        else:
            error = status = np.full(m, -1, dtype=np.int64)
        decoded = DecodedReplies(
            verdict=verdict,
            index=self._index[k],
            motor_id=self._can_id[k],
            state=values,
            temperature=d6 + t[:, 6],
            rotor_temperature=d7 + t[:, 8],
            error_code=error,
            voltage=d6 * t[:, 7],
            status=status,
        )
        # Kept for the next batch when nothing in it depended on more than the key (ids, lengths,
        # byte 0, buses) and the CubeMars error bytes: every frame a reply, no special-frame
        # candidate. (A CubeMars reply's error code is its byte 7, undefined ones corrupt: checked
        # again on every batch.)
        self._steady = None
        if m and not maybe_special.any() and bool((k < n).all()):
            cubemars = self._is_cubemars[k]
            kept = [verdict, decoded.index, decoded.motor_id, error, status]
            kept = [a.copy() for a in kept]
            for a in kept:  # handed out as they are by every steady decode: nobody may write into them
                a.flags.writeable = False
            limit = np.where(cubemars, CUBEMARS_MAX_ERROR, np.iinfo(np.int64).max)  # byte 7 above it: corrupt
            octets = np.ascontiguousarray(batch).view(np.uint8).reshape(m, -1)
            constants = (
                bus.copy(), steady_key(octets), np.ascontiguousarray(t[:, 1:6:2]), np.ascontiguousarray(t[:, 0:6:2]),
                np.ascontiguousarray(t[:, [6, 8, 7]].T), error.copy(), cubemars, limit,
            )  # fmt: skip
            self._steady = (constants, *kept)
        return decoded

    def _decode_steady(self, octets: NDArray[np.uint8], bus: NDArray[np.int64], constants: tuple[NDArray[Any], ...],
                       verdict: NDArray[Any], index: NDArray[Any], motor_id: NDArray[Any], error: NDArray[Any],
                       status: NDArray[Any]) -> DecodedReplies | None:  # fmt: skip
        """:meth:`decode` of a batch (``octets``: its frames' bytes) whose key repeats the kept
        one's: the same arithmetic on the payload (:func:`~giwbc.hal.kernels.steady_replies`), the
        rest handed out from the kept batch (read-only arrays); None when the key differs or a
        CubeMars reply carries an undefined error byte (the full decode says corrupt)."""
        m = octets.shape[0]
        values = np.empty((m, 3))
        extra = np.empty((3, m))
        error_out = np.empty(m, dtype=np.int64)
        if not steady_replies(octets, np.ascontiguousarray(bus), *constants, values, extra, error_out):
            return None
        return DecodedReplies(verdict, index, motor_id, values, extra[0], extra[1], error_out, extra[2], status)


def _as_bytes(data: Any) -> bytes:
    if type(data) is bytes:
        return data
    if isinstance(data, (int, str)) or data is None:
        raise CorruptFrameError(f"frame data must be bytes, got {type(data).__name__}")
    return bytes(data)


def _byte(x: float) -> int:
    """Nearest unsigned byte, saturating (NaN -> 0)."""
    if x != x:
        return 0
    return int(min(255, max(0, round(x))))
