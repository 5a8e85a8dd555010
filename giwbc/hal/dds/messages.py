"""``LowCmd_`` and ``LowState_`` read and written in place, in their serialized (wire) form.

:class:`WireMessage` holds one message's wire bytes and numpy views of its fields
(:mod:`giwbc.hal.dds.layout`). :meth:`WireMessage.seal` stamps Unitree's CRC
(:mod:`giwbc.hal.dds.crc`, computed over the C layout, kept in a second buffer) and returns the
bytes to publish; :meth:`WireMessage.load` takes received bytes and says whether they are a
well-formed message of this type with a valid CRC. Per message: two buffer copies, the CRC, no
Python objects per motor.
"""

from __future__ import annotations

import numpy as np

from giwbc.hal.dds.crc import unitree_crc
from giwbc.hal.dds.layout import (
    CMD_RESERVE, HEADER, LOWCMD_C, LOWCMD_WIRE, LOWSTATE_C, LOWSTATE_WIRE, MOTORS, STATE_MOTORSTATE, STATE_TEMPERATURE, Layout,
)  # fmt: skip

_HEADER = np.frombuffer(HEADER, dtype=np.uint8)
OK, BAD_SIZE, BAD_HEADER, BAD_CRC = "ok", "size", "header", "crc"


class WireMessage:
    """One message of ``wire`` layout (its C twin ``c`` for the CRC), with views of its fields."""

    def __init__(self, wire: Layout, c: Layout) -> None:
        self.wire_layout, self.c_layout = wire, c
        self.buffer = np.zeros(wire.size, dtype=np.uint8)
        self.buffer[:4] = _HEADER
        self._c = np.zeros(c.size, dtype=np.uint8)
        self._wire_modes, self._c_modes = np.array(wire.mode), np.array(c.mode)
        self.floats = wire.motor_floats(self.buffer)  # (MOTORS, n) float32, in place
        self.crc_word = np.ndarray((1,), dtype="<u4", buffer=self.buffer, offset=wire.crc)
        # The C struct is the wire payload with padding put in before motor 0 (a CDR struct is not
        # padded to its alignment): the fields before motor 0's mode byte where they are, that byte
        # moved to its aligned slot, and everything from motor 0's first float on 4 bytes later.
        self._head = wire.mode[0]  # wire offset of motor 0's mode (= the payload's fields before it, plus the header)
        self._mode0 = c.mode[0]
        self._body = wire.floats
        self.status = "empty"

    @property
    def modes(self) -> np.ndarray:
        """The motors' mode bytes (a copy)."""
        return self.buffer[self._wire_modes]

    def set_modes(self, modes: np.ndarray) -> None:
        self.buffer[self._wire_modes] = modes

    def field(self, name: str) -> np.ndarray:
        """A view of a message-level field (``tick``, ``quaternion``, ``mode_pr``, ...)."""
        return self.wire_layout.field(self.buffer, name)

    def motor_field(self, spec: tuple[int, str, int]) -> np.ndarray:
        """A (MOTORS, count) view of a per-motor field (``STATE_TEMPERATURE``, ...)."""
        return self.wire_layout.motor_words(self.buffer, *spec)

    def c_struct(self) -> np.ndarray:
        """The message in Unitree's C layout (what the CRC covers), refreshed from the wire bytes."""
        c, b, head = self._c, self.buffer, self._head
        c[: head - 4] = b[4:head]
        c[self._mode0] = b[head]
        c[self._mode0 + 4 :] = b[self._body :]  # (the padding between stays zero: never written)
        return c

    def crc(self) -> int:
        """The CRC the fields call for."""
        return unitree_crc(self.c_struct())

    def seal(self) -> bytes:
        """Stamp the CRC; the bytes to publish."""
        self.crc_word[0] = self.crc()
        return self.buffer.tobytes()

    def load(self, data: bytes) -> str:
        """Take received bytes: ``"ok"``, or why not (``"size"``, ``"header"``, ``"crc"``; the
        fields hold the bytes anyway, except for a wrong size)."""
        if len(data) < self.buffer.size or len(data) > self.buffer.size + 3:  # (Cyclone pads to 4 bytes)
            self.status = BAD_SIZE
            return BAD_SIZE
        self.buffer[:] = np.frombuffer(data, dtype=np.uint8, count=self.buffer.size)
        if data[:2] != HEADER[:2]:
            self.status = BAD_HEADER
        else:
            self.status = OK if int(self.crc_word[0]) == self.crc() else BAD_CRC
        return self.status


class LowCmd(WireMessage):
    """``unitree_hg::msg::dds_::LowCmd_``: per motor slot mode, q, dq, tau, kp, kd."""

    def __init__(self) -> None:
        super().__init__(LOWCMD_WIRE, LOWCMD_C)
        f = self.floats
        self.q, self.dq, self.tau, self.kp, self.kd = (f[:, k] for k in range(5))  # IDL order: q, dq, tau, kp, kd
        self.reserve = self.motor_field(CMD_RESERVE)[:, 0]


class LowState(WireMessage):
    """``unitree_hg::msg::dds_::LowState_``: per motor slot mode, q, dq, ddq, tau_est, temperatures,
    error bits (``motorstate``); the IMU (quaternion w, x, y, z; gyroscope; accelerometer); a tick."""

    def __init__(self) -> None:
        super().__init__(LOWSTATE_WIRE, LOWSTATE_C)
        f = self.floats
        self.q, self.dq, self.ddq, self.tau_est = (f[:, k] for k in range(4))
        self.temperature = self.motor_field(STATE_TEMPERATURE)
        self.motorstate = self.motor_field(STATE_MOTORSTATE)[:, 0]
        self.tick = self.field("tick")
        self.quaternion = self.field("quaternion")
        self.gyroscope = self.field("gyroscope")
        self.accelerometer = self.field("accelerometer")
        self.mode_machine = self.field("mode_machine")


__all__ = ["BAD_CRC", "BAD_HEADER", "BAD_SIZE", "OK", "LowCmd", "LowState", "WireMessage"]
