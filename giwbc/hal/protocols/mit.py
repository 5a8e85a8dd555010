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
cubemars    8      original + byte 6 = temperature, °C + 40 (-40..215 °C, CubeMars AK
                   manual) + byte 7 = error code (0 = none, see ``CUBEMARS_ERRORS``)
damiao      8      byte 0 = state << 4 | (id & 0x0F), p16, v12, t12, MOS temperature °C,
                   rotor temperature °C. ``error_code`` = state if state >= 8 else 0.
==========  =====  ======================================================================

The variant is a property of the motor (``MotorConfig.reply``); two motors whose replies could be
confused (same length and byte 0) are refused when the protocol is built.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from giwbc.hal.motor import RANGE_FIELDS, MotorConfig
from giwbc.hal.protocols.base import (
    ActuatorProtocol,
    CanFrame,
    CanProtocolError,
    CommandBatch,
    CommandValueError,
    CorruptFrameError,
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
_P_LEVELS, _VT_LEVELS = 65535, 4095

ENTER_MOTOR_MODE = b"\xff" * 7 + b"\xfc"
EXIT_MOTOR_MODE = b"\xff" * 7 + b"\xfd"
SET_ZERO = b"\xff" * 7 + b"\xfe"
CLEAR_ERRORS = b"\xff" * 7 + b"\xfb"  # Damiao
_SPECIAL_LAST = frozenset({0xFB, 0xFC, 0xFD, 0xFE})
_SPECIAL_NAMES = MappingProxyType({0xFC: "enter", 0xFD: "exit", 0xFE: "zero", 0xFB: "clear"})

CUBEMARS_TEMPERATURE_OFFSET = -40.0  # °C = byte + offset
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


def _pack(bounds: tuple[tuple[float, float, float, int], ...], values: tuple[float, ...]) -> tuple[bytes, Any]:
    word = 0
    clamped = []
    for (lo, hi, span, levels), shift, x in zip(bounds, _SHIFTS, values):
        x = float(x)
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


@dataclass(frozen=True, slots=True)
class ReplyBatch:
    """Vectorized decode result, one row per input frame. ``index`` is the motor's index in the
    protocol's order, -1 where the row is not a valid reply (its values are NaN)."""

    index: NDArray[np.int64]
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]
    torque: NDArray[np.float64]
    temperature: NDArray[np.float64]  # NaN where not reported
    error_code: NDArray[np.int64]  # -1 where not reported

    @property
    def valid(self) -> NDArray[np.bool_]:
        return self.index >= 0


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
        n = len(self.motors)
        self._variants: tuple[ReplyVariant, ...] = tuple(self._variant(m) for m in self.motors)
        self._bounds = [_bounds(m) for m in self.motors]
        # Demultiplexing table: key (length << 8 | byte 0) -> motor index.
        self._lut: dict[int, int] = {}
        self._by_byte0: dict[int, int] = {}
        lut = np.full((9, 256), -1, dtype=np.int64)
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
                keys = [(s << 4) | (m.can_id & 0x0F) for s in range(16)]
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
                lut[var.length, b0] = i
        # Per-motor decode scales (u * scale + lo, same expression in scalar and vector paths).
        self._dec = [
            (m.model.position.min, m.model.position.span / _P_LEVELS,
             m.model.velocity.min, m.model.velocity.span / _VT_LEVELS,
             m.model.torque.min, m.model.torque.span / _VT_LEVELS)
            for m in self.motors
        ]  # fmt: skip
        self._dec_array = np.array(self._dec, dtype=float).reshape(n, 6)
        # decode_batch tables: an extra row N (all NaN, code -1) stands for "not a valid reply".
        temp_offset = [
            {_CUBEMARS: CUBEMARS_TEMPERATURE_OFFSET, _DAMIAO: 0.0}.get(v.code, math.nan) for v in self._variants
        ]
        self._dec_batch = np.vstack(
            [np.column_stack([self._dec_array, np.array(temp_offset).reshape(n, 1)]), np.full((1, 7), np.nan)]
        )
        self._code_batch = np.array([v.code for v in self._variants] + [-1], dtype=np.int64)
        self._lut_batch = np.vstack([np.where(lut < 0, n, lut), np.full((1, 256), n, dtype=np.int64)])
        self._lo = np.array([[r.min for r in m.model.ranges] for m in self.motors], dtype=float).reshape(n, 5)
        self._hi = np.array([[r.max for r in m.model.ranges] for m in self.motors], dtype=float).reshape(n, 5)
        self._span = self._hi - self._lo
        self._arb_ids = np.array([m.can_id for m in self.motors], dtype=np.int64)

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
        n = len(self.motors)
        x = np.empty((n, 5), dtype=float)
        x[:, 0] = position
        x[:, 1] = velocity
        x[:, 2] = kp
        x[:, 3] = kd
        x[:, 4] = torque
        nan = np.isnan(x)
        if nan.any():
            bad = [f"{self.motors[i].joint}.{RANGE_FIELDS[j]}" for i, j in zip(*np.nonzero(nan))]
            raise CommandValueError(f"NaN in commands: {', '.join(bad)}")
        clamped = (x < self._lo) | (x > self._hi)
        np.clip(x, self._lo, self._hi, out=x)
        x -= self._lo
        x *= _LEVELS_F
        x /= self._span
        x -= 0.5
        np.ceil(x, out=x)
        words = np.bitwise_or.reduce(x.astype(np.uint64) << _SHIFTS_U, axis=1)
        data = words.astype(">u8").view(np.uint8).reshape(n, 8)
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
        if n == 0 or n > 8:
            raise FrameLengthError(f"MIT replies have 6 to 8 bytes, got {n}")
        b0 = data[0]
        i = self._lut.get((n << 8) | b0)
        if i is None:
            j = self._by_byte0.get(b0)
            if j is not None:
                var = self._variants[j]
                raise FrameLengthError(
                    f"motor id {self.motors[j].can_id} replies with {var.length} bytes ({var.name}), got {n}"
                )
            raise UnknownMotorError(f"no motor on this bus replies with byte 0 = 0x{b0:02X} in {n} bytes")
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

    def decode_batch(self, data: ArrayLike, lengths: ArrayLike | None = None) -> ReplyBatch:
        """Decode M frames at once: ``data`` (M, 8) uint8 (shorter payloads zero-padded), ``lengths``
        (M,) payload lengths (default 8). Rows that :meth:`decode` would reject get index -1.
        Arbitration ids are not checked here (filter foreign and extended frames before)."""
        d = np.asarray(data, dtype=np.uint8)
        if d.ndim != 2 or d.shape[1] != 8:
            raise ValueError(f"data must be (M, 8), got {d.shape}")
        m = d.shape[0]
        ln = np.full(m, 8, dtype=np.int64) if lengths is None else np.asarray(lengths, dtype=np.int64).reshape(m)
        # Row 9 of the table is all "no motor" (index N, a NaN sentinel row of the per-motor tables).
        k = self._lut_batch[np.clip(ln, 0, 9), d[:, 0]]
        last = d[:, 7]
        special = (ln == 8) & (last >= 0xFB) & (last <= 0xFE) & (d[:, :7] == 0xFF).all(axis=1)
        k[special] = len(self.motors)
        di = d.astype(np.int64)
        sc = self._dec_batch[k]
        p = ((di[:, 1] << 8) | di[:, 2]) * sc[:, 1] + sc[:, 0]
        v = ((di[:, 3] << 4) | (di[:, 4] >> 4)) * sc[:, 3] + sc[:, 2]
        t = (((di[:, 4] & 0x0F) << 8) | di[:, 5]) * sc[:, 5] + sc[:, 4]
        temp = di[:, 6] + sc[:, 6]  # NaN offset where the variant reports no temperature
        state = di[:, 0] >> 4
        code = self._code_batch[k]
        err = np.where(
            code == _CUBEMARS, di[:, 7], np.where(code == _DAMIAO, np.where(state >= 8, state, 0), -1)
        )
        idx = np.where(k == len(self.motors), -1, k)
        return ReplyBatch(idx, p, v, t, temp, err)

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
