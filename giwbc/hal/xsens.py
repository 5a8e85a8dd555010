"""Xsens MTi binary protocol ("Xbus", MTData2 messages): an incremental parser, an encoder, and
the serial IMU source built on them.

Reference: Xsens, *MT Low Level Communication Protocol Documentation* (document MT0101P), the
public specification of the MTi 1/10/100/600-series serial protocol. What this module relies on:

- **Message**: preamble ``0xFA``, bus id (``0xFF`` = the master device), message id (``0x36`` =
  MTData2), length byte, payload, checksum. A length byte of ``0xFF`` announces an *extended*
  message: the next two bytes are the payload length, big-endian (up to 2048 bytes).
- **Checksum**: one byte such that the sum of every byte after the preamble (bus id, message
  id, length byte(s), payload, checksum) is 0 modulo 256. (The spec's own example, GoToConfig:
  ``FA FF 30 00 D1``.)
- **MTData2 payload**: data items, each a 2-byte big-endian XDI data identifier, a 1-byte size
  and the data. The identifier's low nibble gives the number format (bits 0-1: ``00`` float32,
  ``11`` float64; 12.20 / 16.32 fixed point are not decoded here) and the coordinate system
  (bits 2-3: ``00`` ENU, ``01`` NED, ``10`` NWU). All multi-byte numbers are big-endian.
- Items used: PacketCounter ``0x1020`` (uint16), SampleTimeFine ``0x1060`` (uint32, ticks of
  10 kHz), Quaternion ``0x2010`` (q0..q3 = w, x, y, z: sensor frame to the ENU frame), Acceleration
  ``0x4020`` (calibrated specific force in the sensor frame, m/s^2, +9.81 up at rest), RateOfTurn
  ``0x8020`` (sensor frame, rad/s), StatusWord ``0xE020`` (uint32). Other items are skipped.

Orientation is accepted in ENU only (the world frame of this project, z up): an NED or NWU
quaternion item is counted as unsupported, so a device configured otherwise reads as "no
orientation", never as a silently wrong one. Configure the device (MT Manager, or the
SetOutputConfiguration message) to output ``0x1020, 0x1060, 0x2010, 0x4020, 0x8020`` at the
control rate or above.

The parser never raises on input: bytes that do not start a well-formed message are dropped one
at a time until the next preamble that does (resynchronisation), and what was dropped is counted
(:class:`XbusCounters`). A message whose checksum fails is counted and skipped by its first byte
only, so a true message hidden inside it is still found.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import serial

from giwbc.errors import HardwareConfigError
from giwbc.robot.interface import ImuReading

PREAMBLE = 0xFA
BUS_ID_MASTER = 0xFF
MID_MTDATA2 = 0x36
EXTENDED_LENGTH = 0xFF
MAX_PAYLOAD = 2048  # the spec's limit for extended messages

XDI_PACKET_COUNTER = 0x1020
XDI_SAMPLE_TIME_FINE = 0x1060
XDI_QUATERNION = 0x2010
XDI_ACCELERATION = 0x4020
XDI_RATE_OF_TURN = 0x8020
XDI_STATUS_WORD = 0xE020
SAMPLE_TIME_FINE_HZ = 10_000.0

_FORMAT_MASK = 0x0003
_COORD_MASK = 0x000C
_FLOAT_FORMATS = {0x0: ">f4", 0x3: ">f8"}  # float32, float64 (fixed point: not decoded)
_VECTOR_ITEMS = {XDI_QUATERNION: 4, XDI_ACCELERATION: 3, XDI_RATE_OF_TURN: 3}


@dataclass
class XbusCounters:
    """What the parser saw; a growing ``checksum_errors`` or ``discarded_bytes`` means a noisy
    line or a wrong baud rate."""

    bytes_in: int = 0
    messages: int = 0  # well-formed messages of any id
    samples: int = 0  # MTData2 messages decoded
    checksum_errors: int = 0
    discarded_bytes: int = 0  # dropped while resynchronising
    malformed: int = 0  # MTData2 payloads whose items overrun the payload
    unsupported_items: int = 0  # known quantities in a format or frame not decoded here
    other_messages: int = 0  # well-formed messages that are not MTData2 (acks, errors, ...)

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class MtSample:
    """One decoded MTData2 message; quantities the message did not carry are None."""

    packet_counter: int | None = None
    sample_time_fine: int | None = None  # ticks of 10 kHz, wraps at 2**32
    quaternion: np.ndarray | None = None  # (x, y, z, w), sensor frame in ENU
    acceleration: np.ndarray | None = None  # m/s^2, sensor frame
    rate_of_turn: np.ndarray | None = None  # rad/s, sensor frame
    status_word: int | None = None

    @property
    def complete(self) -> bool:
        """Carries everything an :class:`ImuReading` needs."""
        return self.quaternion is not None and self.acceleration is not None and self.rate_of_turn is not None


# ----------------------------------------------------------------------------- encoding
def checksum(body: bytes | bytearray) -> int:
    """The checksum byte for ``body`` = every byte after the preamble, checksum excluded."""
    return (-sum(body)) & 0xFF


def encode_message(mid: int, payload: bytes, bus_id: int = BUS_ID_MASTER) -> bytes:
    """A complete Xbus message (extended length when the payload has 255 bytes or more)."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"Xbus payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    if len(payload) < EXTENDED_LENGTH:
        body = bytes((bus_id, mid, len(payload))) + payload
    else:
        body = bytes((bus_id, mid, EXTENDED_LENGTH)) + struct.pack(">H", len(payload)) + payload
    return bytes((PREAMBLE,)) + body + bytes((checksum(body),))


def encode_item(data_id: int, data: bytes) -> bytes:
    """One MTData2 data item."""
    if len(data) > 255:
        raise ValueError(f"an MTData2 item carries at most 255 bytes, got {len(data)}")
    return struct.pack(">HB", data_id, len(data)) + data


def encode_mtdata2(sample: MtSample, *, extra_items: Iterable[bytes] = ()) -> bytes:
    """The MTData2 message an MTi would send for ``sample`` (float32, ENU), items in the order
    counter, sample time, quaternion, acceleration, rate of turn, status word."""
    items: list[bytes] = []
    if sample.packet_counter is not None:
        items.append(encode_item(XDI_PACKET_COUNTER, struct.pack(">H", sample.packet_counter & 0xFFFF)))
    if sample.sample_time_fine is not None:
        items.append(encode_item(XDI_SAMPLE_TIME_FINE, struct.pack(">I", sample.sample_time_fine & 0xFFFFFFFF)))
    if sample.quaternion is not None:
        x, y, z, w = np.asarray(sample.quaternion, dtype=float)
        items.append(encode_item(XDI_QUATERNION, np.array([w, x, y, z], dtype=">f4").tobytes()))
    if sample.acceleration is not None:
        items.append(encode_item(XDI_ACCELERATION, np.asarray(sample.acceleration, dtype=">f4").tobytes()))
    if sample.rate_of_turn is not None:
        items.append(encode_item(XDI_RATE_OF_TURN, np.asarray(sample.rate_of_turn, dtype=">f4").tobytes()))
    if sample.status_word is not None:
        items.append(encode_item(XDI_STATUS_WORD, struct.pack(">I", sample.status_word & 0xFFFFFFFF)))
    items.extend(extra_items)
    return encode_message(MID_MTDATA2, b"".join(items))


def sample_of_reading(reading: ImuReading, packet_counter: int) -> MtSample:
    """The MTData2 sample a device would report for ``reading`` (time in SampleTimeFine ticks)."""
    return MtSample(
        packet_counter=packet_counter & 0xFFFF,
        sample_time_fine=int(round(reading.time * SAMPLE_TIME_FINE_HZ)) & 0xFFFFFFFF,
        quaternion=np.asarray(reading.quaternion, dtype=float),
        acceleration=np.asarray(reading.linear_acceleration, dtype=float),
        rate_of_turn=np.asarray(reading.angular_velocity, dtype=float),
    )


# ----------------------------------------------------------------------------- decoding
def decode_mtdata2(payload: bytes, counters: XbusCounters | None = None) -> MtSample | None:
    """The sample in an MTData2 payload; None (and ``counters.malformed`` + 1) when an item
    overruns the payload."""
    c = counters if counters is not None else XbusCounters()
    values: dict[str, Any] = {}
    k, n = 0, len(payload)
    while k < n:
        if k + 3 > n:
            c.malformed += 1
            return None
        data_id, size = struct.unpack_from(">HB", payload, k)
        k += 3
        if k + size > n:
            c.malformed += 1
            return None
        data = payload[k : k + size]
        k += size
        _decode_item(data_id, data, values, c)
    return MtSample(**values)


def _decode_item(data_id: int, data: bytes, out: dict[str, Any], c: XbusCounters) -> None:
    if data_id == XDI_PACKET_COUNTER and len(data) == 2:
        out["packet_counter"] = struct.unpack(">H", data)[0]
        return
    if data_id == XDI_SAMPLE_TIME_FINE and len(data) == 4:
        out["sample_time_fine"] = struct.unpack(">I", data)[0]
        return
    if data_id == XDI_STATUS_WORD and len(data) == 4:
        out["status_word"] = struct.unpack(">I", data)[0]
        return
    base = data_id & ~(_FORMAT_MASK | _COORD_MASK)
    if base not in _VECTOR_ITEMS:
        return  # an item this driver does not use
    fmt = _FLOAT_FORMATS.get(data_id & _FORMAT_MASK)
    count = _VECTOR_ITEMS[base]
    if fmt is None or (data_id & _COORD_MASK) != 0 or len(data) != count * int(fmt[-1]):
        c.unsupported_items += 1
        return
    v = np.frombuffer(data, dtype=fmt).astype(np.float64)
    if not np.all(np.isfinite(v)):
        c.unsupported_items += 1
        return
    if base == XDI_QUATERNION:
        out["quaternion"] = np.array([v[1], v[2], v[3], v[0]])
    elif base == XDI_ACCELERATION:
        out["acceleration"] = v
    else:
        out["rate_of_turn"] = v


class XbusParser:
    """Incremental Xbus parser: :meth:`feed` any chunk of bytes, get the MTData2 samples completed
    by it. Keeps at most one unfinished message between calls."""

    def __init__(self, max_payload: int = MAX_PAYLOAD) -> None:
        self.max_payload = max_payload
        self.counters = XbusCounters()
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a message."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[MtSample]:
        c = self.counters
        c.bytes_in += len(data)
        buf = self._buf
        buf += data
        out: list[MtSample] = []
        start = 0
        while True:
            at = buf.find(PREAMBLE, start)
            if at < 0:
                c.discarded_bytes += len(buf) - start
                start = len(buf)
                break
            c.discarded_bytes += at - start
            start = at
            avail = len(buf) - at
            if avail < 4:
                break
            bus_id, mid, length = buf[at + 1], buf[at + 2], buf[at + 3]
            header = 4
            if length == EXTENDED_LENGTH:
                if avail < 6:
                    break
                length = (buf[at + 4] << 8) | buf[at + 5]
                header = 6
            if bus_id != BUS_ID_MASTER or length > self.max_payload:
                c.discarded_bytes += 1  # not a message start: resynchronise on the next preamble
                start = at + 1
                continue
            total = header + length + 1
            if avail < total:
                break
            if sum(buf[at + 1 : at + total]) & 0xFF:
                c.checksum_errors += 1
                c.discarded_bytes += 1
                start = at + 1
                continue
            c.messages += 1
            start = at + total
            if mid != MID_MTDATA2:
                c.other_messages += 1
                continue
            sample = decode_mtdata2(bytes(buf[at + header : at + header + length]), c)
            if sample is not None:
                c.samples += 1
                out.append(sample)
        del buf[:start]
        return out


# ----------------------------------------------------------------------------- the serial IMU
class ByteStream(Protocol):
    """What the driver needs of a serial port (``serial.Serial`` has it; so does a pty wrapper)."""

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def close(self) -> None: ...


@dataclass
class _Unwrap:
    """Unwraps a 32-bit tick counter into seconds."""

    last: int | None = None
    wraps: int = 0

    def seconds(self, ticks: int) -> float:
        if self.last is not None and ticks < self.last and self.last - ticks > 1 << 31:
            self.wraps += 1
        self.last = ticks
        return (ticks + (self.wraps << 32)) / SAMPLE_TIME_FINE_HZ


@dataclass
class XsensImu:
    """An :class:`~giwbc.hal.can_robot.ImuSource` reading an Xsens MTi on a byte stream.

    :meth:`read` drains what the port holds (never blocks), parses it, and returns the newest
    complete sample as an :class:`ImuReading`; its ``time`` is the device's SampleTimeFine
    (unwrapped, s) when the device sends it, else the host clock at arrival. The same reading is
    returned until a new sample arrives, which is how the estimator's stale-IMU check sees a
    silent device.
    """

    port: ByteStream
    clock: Callable[[], float] = time.monotonic
    parser: XbusParser = field(default_factory=XbusParser)
    incomplete: int = 0  # samples lacking orientation, rate of turn or acceleration
    last_sample: MtSample | None = None
    _latest: ImuReading | None = None
    _unwrap: _Unwrap = field(default_factory=_Unwrap)

    @property
    def counters(self) -> dict[str, int]:
        return {**self.parser.counters.as_dict(), "incomplete": self.incomplete}

    def poll(self) -> int:
        """Read and parse what the port holds; the number of complete samples it brought."""
        waiting = self.port.in_waiting
        if not waiting:
            return 0
        got = 0
        for s in self.parser.feed(self.port.read(waiting)):
            if not s.complete:
                self.incomplete += 1
                continue
            t = self._unwrap.seconds(s.sample_time_fine) if s.sample_time_fine is not None else self.clock()
            self._latest = ImuReading(s.quaternion, s.rate_of_turn, s.acceleration, t)  # type: ignore[arg-type]
            self.last_sample = s
            got += 1
        return got

    def read(self) -> ImuReading | None:
        self.poll()
        return self._latest

    def close(self) -> None:
        self.port.close()


def open_serial_imu(device: str, baudrate: int | None = None, **kwargs: Any) -> XsensImu:
    """Open ``device`` with pyserial (8N1, non-blocking reads) and wrap it in :class:`XsensImu`.
    The MTi's factory baud rate is 115200; high output rates need 921600 or more."""
    try:
        port = serial.Serial(device, baudrate=baudrate or 115200, timeout=0, **kwargs)
    except (serial.SerialException, OSError) as e:
        raise HardwareConfigError(f"cannot open the serial IMU at {device!r}: {e}") from e
    return XsensImu(port)


__all__ = [
    "MtSample",
    "XbusCounters",
    "XbusParser",
    "XsensImu",
    "checksum",
    "decode_mtdata2",
    "encode_item",
    "encode_message",
    "encode_mtdata2",
    "open_serial_imu",
    "sample_of_reading",
]
