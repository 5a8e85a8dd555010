"""Byte layouts of Unitree's ``unitree_hg`` low-level messages (``LowCmd_``, ``LowState_``), from
Unitree's public IDL (``unitree_sdk2``: ``unitree_hg/msg/dds_/*.idl``), as numpy views.

Two layouts of the same fields matter:

* **on the wire** (:data:`LOWCMD_WIRE`, :data:`LOWSTATE_WIRE`): XCDR1, little endian, after the
  4-byte encapsulation header ``00 01 00 00``; every field aligned to its own size relative to the
  payload's start. A struct is not padded to its alignment in CDR, so the first motor's ``mode``
  byte follows ``mode_machine`` directly (payload offset 2) and the motor records are not one
  stride from the start; the float fields of every motor are (stride 28 / 56 bytes).
* **in memory** (:data:`LOWCMD_C`, :data:`LOWSTATE_C`): the C structs of Unitree's SDK (natural
  alignment, every struct padded to 4). Unitree's CRC runs over this layout, not over the wire
  bytes (:mod:`giwbc.hal.dds.crc`).

IDL (field order and array sizes)::

    MotorCmd_   { uint8 mode; float q, dq, tau, kp, kd; uint32 reserve; }
    LowCmd_     { uint8 mode_pr; uint8 mode_machine; MotorCmd_ motor_cmd[35]; uint32 reserve[4]; uint32 crc; }
    IMUState_   { float quaternion[4] (w, x, y, z); float gyroscope[3]; float accelerometer[3]; float rpy[3]; int16 temperature; }
    MotorState_ { uint8 mode; float q, dq, ddq, tau_est; int16 temperature[2]; float vol; uint32 sensor[2];
                  uint32 motorstate; uint32 reserve[4]; }
    LowState_   { uint32 version[2]; uint8 mode_pr; uint8 mode_machine; uint32 tick; IMUState_ imu_state;
                  MotorState_ motor_state[35]; uint8 wireless_remote[40]; uint32 reserve[4]; uint32 crc; }

:class:`Layout` gives numpy views of one buffer in either layout (fields written and read in
place: nothing allocated per message).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MOTORS = 35  # motor slots in every unitree_hg message (the G1 uses 29)
HEADER = b"\x00\x01\x00\x00"  # XCDR1 (PLAIN_CDR), little endian, no options


@dataclass(frozen=True)
class Layout:
    """Where each field of a message lies in a byte buffer (offsets from the buffer's start).

    ``mode``: offset of each motor's mode byte; ``floats``: offset of motor 0's first float field
    and the motor stride (``nfloat`` consecutive float32 per motor); ``size``: whole buffer."""

    name: str
    size: int
    mode: tuple[int, ...]
    floats: int
    stride: int
    nfloat: int
    fields: dict[str, tuple[int, str, int]]  # name -> (offset, dtype, count) of the other fields
    crc: int  # offset of the crc word

    def motor_floats(self, buf: np.ndarray) -> np.ndarray:
        """(MOTORS, nfloat) float32 view of the motors' float fields of ``buf`` (a uint8 array)."""
        return np.ndarray((MOTORS, self.nfloat), dtype="<f4", buffer=buf, offset=self.floats, strides=(self.stride, 4))

    def motor_words(self, buf: np.ndarray, offset: int, dtype: str, count: int) -> np.ndarray:
        """(MOTORS, count) view of per-motor fields ``offset`` bytes after the motor's first float
        (``offset, dtype, count``: one of the ``STATE_*`` / ``CMD_*`` triples)."""
        item = np.dtype(dtype).itemsize
        return np.ndarray((MOTORS, count), dtype=dtype, buffer=buf, offset=self.floats + offset, strides=(self.stride, item))

    def modes(self, buf: np.ndarray) -> np.ndarray:
        """The motors' mode bytes (a copy: they are not one stride apart on the wire)."""
        return buf[list(self.mode)]

    def field(self, buf: np.ndarray, name: str) -> np.ndarray:
        offset, dtype, count = self.fields[name]
        return np.ndarray((count,), dtype=dtype, buffer=buf, offset=offset)


def _lowcmd(wire: bool) -> Layout:
    h = 4 if wire else 0  # the encapsulation header precedes the payload on the wire
    if wire:  # mode_pr @0, mode_machine @1, motor 0's mode @2, its q @4; later motors: mode @28 i, q @28 i + 4
        modes = (h + 2, *(h + 28 * i for i in range(1, MOTORS)))
        floats = h + 4
    else:  # C: motor i at 4 + 28 i (mode, 3 bytes of padding, floats)
        modes = tuple(4 + 28 * i for i in range(MOTORS))
        floats = 8
    end = floats - 4 + 28 * MOTORS  # after the last motor record
    fields = {"mode_pr": (h + 0, "u1", 1), "mode_machine": (h + 1, "u1", 1), "reserve": (end, "<u4", 4)}
    return Layout("LowCmd_ " + ("wire" if wire else "C"), end + 20, modes, floats, 28, 5, fields, end + 16)


def _lowstate(wire: bool) -> Layout:
    h = 4 if wire else 0
    imu = 16  # version[2] @0, mode_pr @8, mode_machine @9, tick @12 (both layouts)
    if wire:  # IMU 54 bytes (ends @70): motor 0's mode @70, q @72; motor i: mode @68 + 56 i, q @72 + 56 i
        modes = (h + 70, *(h + 68 + 56 * i for i in range(1, MOTORS)))
        floats = h + 72
    else:  # C: IMU padded to 56 (ends @72): motor i at 72 + 56 i, q 4 bytes later
        modes = tuple(72 + 56 * i for i in range(MOTORS))
        floats = 76
    end = floats - 4 + 56 * MOTORS
    fields = {
        "version": (h + 0, "<u4", 2), "mode_pr": (h + 8, "u1", 1), "mode_machine": (h + 9, "u1", 1), "tick": (h + 12, "<u4", 1),
        "quaternion": (h + imu, "<f4", 4), "gyroscope": (h + imu + 16, "<f4", 3), "accelerometer": (h + imu + 28, "<f4", 3),
        "rpy": (h + imu + 40, "<f4", 3), "imu_temperature": (h + imu + 52, "<i2", 1),
        "wireless_remote": (end, "u1", 40), "reserve": (end + 40, "<u4", 4),
    }  # fmt: skip
    return Layout("LowState_ " + ("wire" if wire else "C"), end + 60, modes, floats, 56, 4, fields, end + 56)


LOWCMD_WIRE, LOWCMD_C = _lowcmd(True), _lowcmd(False)
LOWSTATE_WIRE, LOWSTATE_C = _lowstate(True), _lowstate(False)
# Per-motor fields of MotorState_ after its 4 floats (q, dq, ddq, tau_est), offsets from q:
STATE_TEMPERATURE = (16, "<i2", 2)  # int16[2]: Unitree reports the motor's (winding, housing) temperatures, degC
STATE_VOL = (20, "<f4", 1)
STATE_SENSOR = (24, "<u4", 2)
STATE_MOTORSTATE = (32, "<u4", 1)  # error / status bits (0: no error)
CMD_RESERVE = (20, "<u4", 1)

assert LOWCMD_WIRE.size == LOWCMD_C.size == 1004 and LOWSTATE_WIRE.size == LOWSTATE_C.size == 2092


__all__ = [
    "CMD_RESERVE", "HEADER", "LOWCMD_C", "LOWCMD_WIRE", "LOWSTATE_C", "LOWSTATE_WIRE", "MOTORS", "STATE_MOTORSTATE", "STATE_SENSOR",
    "STATE_TEMPERATURE", "STATE_VOL", "Layout",
]  # fmt: skip
