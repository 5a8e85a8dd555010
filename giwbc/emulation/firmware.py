"""MIT-mode motor firmware, vectorized: the motor-mode states, error codes and the command
decoder / reply encoder for every motor at once (:class:`MitFirmwareCodec`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from giwbc.hal.protocols import ActuatorProtocol, MitProtocol
from giwbc.hal.protocols.mit import COMMAND_LEVELS, CUBEMARS_TEMPERATURE_OFFSET, REPLY_VARIANTS

OFF, MOTOR = 0, 1

# Error codes a motor reports, by reply variant (see giwbc.hal.protocols.mit: CUBEMARS_ERRORS,
# DAMIAO_STATES). Variants without an error field ("original", "voltage") cannot report one.
OVER_CURRENT = {"cubemars": 2, "damiao": 0xA}
OVER_TEMPERATURE = {"cubemars": 1, "damiao": 0xC}


class MitFirmwareCodec:
    """The firmware side of MIT mode for every motor at once (plan order), vectorized.

    Bit-identical to :meth:`MitProtocol.decode_command` and :meth:`MitProtocol.encode_reply` (the
    emulator tests compare them on random values for every reply variant); the emulator answers
    29 motors per cycle, and the scalar calls cost ~10 us per frame.
    """

    _SHIFTS = np.array([48, 36, 24, 12, 0], dtype=np.uint64)
    _LEVELS = np.array(COMMAND_LEVELS, dtype=np.uint64)
    _CODES = {name: k for k, name in enumerate(("original", "voltage", "cubemars", "damiao"))}

    def __init__(self, protocols: Sequence[MitProtocol], motors: Sequence[Any]) -> None:
        lo = np.array([[r.min for r in m.model.ranges] for m in motors], dtype=float)
        span = np.array([[r.span for r in m.model.ranges] for m in motors], dtype=float)
        self.lo, self.span = lo, span
        self.hi = np.array([[r.max for r in m.model.ranges] for m in motors], dtype=float)
        self.levels = np.array(COMMAND_LEVELS, dtype=float)
        self.variant = np.array([self._CODES[m.reply] for m in motors], dtype=np.int64)
        self.length = np.array([REPLY_VARIANTS[m.reply].length for m in motors], dtype=np.int64)
        self.can_id = np.array([m.can_id for m in motors], dtype=np.int64)
        bus_of = [b for b, p in enumerate(protocols) for _ in p.motors]
        self.arb = np.array([protocols[b].host_id or 0 for b in bus_of], dtype=np.int64)
        self.voltage_lsb = np.array([protocols[b].voltage_lsb for b in bus_of], dtype=float)
        # Replies: the position, velocity and torque ranges; byte 0 without Damiao's state nibble.
        fields = [0, 1, 4]
        self._lo3, self._hi3, self._span3 = lo[:, fields].copy(), self.hi[:, fields].copy(), span[:, fields].copy()
        self._levels3 = self.levels[fields].copy()
        self._damiao = self.variant == 3
        self._byte0 = np.where(self._damiao, self.can_id & 0x0F, self.can_id & 0xFF).astype(np.uint64)
        self._variants = set(self.variant.tolist())

    @classmethod
    def for_buses(cls, protocols: Sequence[ActuatorProtocol], motors: Sequence[Any]) -> MitFirmwareCodec | None:
        """The codec when every bus speaks MIT mode, else None (the scalar protocol calls are used)."""
        if all(type(p) is MitProtocol for p in protocols):
            return cls(protocols, motors)  # type: ignore[arg-type]
        return None

    def decode_commands(self, index: np.ndarray, payload: Any) -> tuple[list[str | None], np.ndarray]:
        """8-byte command frames of motors ``index`` (payloads ``(M, 8)`` uint8, or their bytes
        joined): special names (None for a command) and the five values (position, velocity, kp,
        kd, torque; NaN for special frames)."""
        data = np.ascontiguousarray(np.frombuffer(payload, dtype=np.uint8) if isinstance(payload, bytes) else payload, dtype=np.uint8).reshape(-1, 8)
        special_mask = (data[:, :7] == 0xFF).all(axis=1) & (data[:, 7] >= 0xFB) & (data[:, 7] <= 0xFE)
        words = data.view(">u8").reshape(-1).astype(np.uint64)
        codes = (words[:, None] >> self._SHIFTS) & self._LEVELS
        values = codes.astype(float) * self.span[index] / self.levels + self.lo[index]
        values[special_mask] = np.nan
        names = _SPECIAL_NAMES
        special = [names[int(last)] if sp else None for sp, last in zip(special_mask.tolist(), data[:, 7].tolist())]
        return special, values

    def encode_replies(
        self,
        index: np.ndarray,
        position: np.ndarray,
        velocity: np.ndarray,
        torque: np.ndarray,
        temperature: np.ndarray,
        mos_temperature: np.ndarray,
        error: np.ndarray,
        status: np.ndarray,
        voltage: float = 24.0,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reply payloads (M, 8) uint8 (zero-padded), their lengths and arbitration ids.

        Built as one big-endian 64-bit word per reply: byte 0, the position / velocity / torque
        codes (quantized exactly as the protocol's scalar encoder does), bytes 6 and 7."""
        values = np.column_stack((position, velocity, torque))
        if np.isnan(values).any():
            values = np.nan_to_num(values, nan=0.0, posinf=np.inf, neginf=-np.inf)
        lo = self._lo3[index]
        x = np.clip(values, lo, self._hi3[index])
        x -= lo
        x *= self._levels3
        x /= self._span3[index]
        x -= 0.5
        np.ceil(x, out=x)
        word = (x.astype(np.uint64) << _REPLY_SHIFTS).sum(axis=1, dtype=np.uint64)
        byte0 = self._byte0[index]
        damiao = self._damiao[index]
        if 3 in self._variants:
            byte0 = byte0 | (damiao * (np.asarray(status, dtype=np.int64) << 4)).astype(np.uint64)
        word |= byte0 << np.uint64(56)
        if self._variants - {0}:  # variants with bytes 6 and 7
            variant = self.variant[index]
            b6 = np.where(damiao, mos_temperature, np.where(variant == 2, temperature - CUBEMARS_TEMPERATURE_OFFSET,
                          np.where(variant == 1, voltage / self.voltage_lsb[index], 0.0)))  # fmt: skip
            b7 = np.where(damiao, _byte(temperature), np.where(variant == 2, np.minimum(error, 255), 0))
            word |= (_byte(b6).astype(np.uint64) << np.uint64(8)) | b7.astype(np.uint64)
        data = word.astype(">u8").view(np.uint8).reshape(len(index), 8)
        return data, self.length[index], self.arb[index]


_REPLY_SHIFTS = np.array([40, 28, 16], dtype=np.uint64)  # position, velocity, torque codes in the reply word
_SPECIAL_NAMES = {0xFC: "enter", 0xFD: "exit", 0xFE: "zero", 0xFB: "clear"}


def _byte(x: np.ndarray) -> np.ndarray:
    """Nearest unsigned byte, saturating, NaN -> 0 (the protocol's reply byte rule)."""
    x = np.asarray(x, dtype=float)
    return np.clip(np.rint(np.where(np.isnan(x), 0.0, x)), 0, 255).astype(np.int64)



__all__ = ["MOTOR", "OFF", "OVER_CURRENT", "OVER_TEMPERATURE", "MitFirmwareCodec"]
