"""A CAN IMU whose frames are described in ``hardware.toml``: ids, byte layout, types, scales.

CAN IMUs send their measurements as a few periodic frames, each carrying some quantities as
scaled integers (or floats) at fixed byte positions. Vendors differ only in those details, so
they are configuration, not code::

    [imu]
    source = "can"
    bus = "can4"                   # one of the plan's buses (shared with motors)
    rate = 500.0                   # Hz: how often the IMU sends each frame (bus load)
    [[imu.frames]]
    id = 0x50                      # standard 11-bit id (extended = true for 29-bit)
    endian = "little"              # default of the frame's fields ("big" or "little")
    fields = [
      { name = "qw", byte = 0, type = "i16", scale = 3.0517578125e-05 },   # 1/32768
      { name = "qx", byte = 2, type = "i16", scale = 3.0517578125e-05 },
      ...
    ]

A field: ``name``, ``byte`` (offset in the payload), ``type`` (``i8 u8 i16 u16 i32 u32 f32``),
optional ``scale`` (default 1) and ``bias`` (default 0): value = raw * scale + bias, in SI units
(rad, rad/s, m/s^2, s), and optional ``endian`` overriding the frame's. Names:

- orientation: ``qw qx qy qz`` (a quaternion, IMU frame in the world, z up) or ``roll pitch yaw``
  (rad, Z-Y-X: R = Rz(yaw) Ry(pitch) Rx(roll));
- angular rate ``gx gy gz`` (IMU frame, rad/s); specific force ``ax ay az`` (IMU frame, m/s^2,
  +9.81 up at rest);
- optional ``time``: the device's timestamp in seconds after scaling (a tick counter: scale =
  tick period); an unsigned counter's wrap-around is unwrapped. Without it, samples are stamped
  with the host clock when they complete.

A sample is complete when every configured frame has arrived since the previous sample; a frame
arriving twice before that means a lost frame: the partial sample is dropped and counted. Frames
shorter than the layout needs are counted and ignored. :class:`CanImuEncoder` writes the same
bytes from an :class:`ImuReading` (the emulator uses it).
"""

from __future__ import annotations

import math
import time
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from giwbc.util.toml import TomlPlace
from giwbc.errors import HardwareConfigError
from giwbc.hal.bus import frame_bits
from giwbc.hal.frames import CAN_EFF_FLAG, CAN_EFF_MASK, CAN_ERR_FLAG, CAN_RTR_FLAG, CAN_SFF_MASK, FRAME
from giwbc.robot.interface import ImuReading
from giwbc.robot.so3 import quat_to_rpy, rpy_to_quat

FIELD_TYPES = {"i8": "i1", "u8": "u1", "i16": "i2", "u16": "u2", "i32": "i4", "u32": "u4", "f32": "f4"}
QUATERNION = ("qx", "qy", "qz", "qw")
EULER = ("roll", "pitch", "yaw")
GYRO = ("gx", "gy", "gz")
ACCEL = ("ax", "ay", "az")
FIELD_NAMES = (*QUATERNION, *EULER, *GYRO, *ACCEL, "time")
_FRAME_KEYS = {"id", "extended", "endian", "fields"}
_FIELD_KEYS = {"name", "byte", "type", "scale", "bias", "endian"}


@dataclass(frozen=True)
class ImuField:
    """One quantity at a fixed place in a frame."""

    name: str
    byte: int
    dtype: np.dtype
    scale: float = 1.0
    bias: float = 0.0

    @property
    def end(self) -> int:
        return self.byte + self.dtype.itemsize

    def decode(self, payload: bytes) -> float:
        raw = np.frombuffer(payload, dtype=self.dtype, count=1, offset=self.byte)[0]
        return float(raw) * self.scale + self.bias

    def encode(self, value: float, payload: bytearray) -> bool:
        """Write ``value``; True when it had to be clamped to the type's range."""
        raw = (value - self.bias) / self.scale
        clamped = False
        if self.dtype.kind in "iu":
            info = np.iinfo(self.dtype)
            r = int(round(raw)) if math.isfinite(raw) else 0
            clamped = not info.min <= r <= info.max
            raw = min(max(r, int(info.min)), int(info.max))
        payload[self.byte : self.end] = np.array([raw], dtype=self.dtype).tobytes()
        return clamped


@dataclass(frozen=True)
class ImuFrame:
    """One frame of the IMU: its id and fields."""

    can_id: int
    extended: bool
    fields: tuple[ImuField, ...]

    @property
    def length(self) -> int:
        """Payload bytes the fields need (the IMU may send more)."""
        return max(f.end for f in self.fields)

    @property
    def wire_id(self) -> int:
        """The id as SocketCAN's ``can_id`` carries it (EFF flag for extended ids)."""
        return self.can_id | CAN_EFF_FLAG if self.extended else self.can_id


@dataclass(frozen=True)
class CanImuLayout:
    """The frames of a CAN IMU and how often it sends them."""

    frames: tuple[ImuFrame, ...]
    rate: float

    @property
    def euler(self) -> bool:
        return any(f.name == "roll" for fr in self.frames for f in fr.fields)

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(f.can_id for f in self.frames)

    def frames_per_cycle(self, control_rate: float) -> int:
        """Frames of each id per control cycle, rounded up (for the bus-capacity check)."""
        return max(1, math.ceil(self.rate / control_rate - 1e-9))

    def bits_per_cycle(self, control_rate: float, *, worst_case: bool = False) -> int:
        """Bus bit times the IMU takes per control cycle (whole frames, rounded up)."""
        n = self.frames_per_cycle(control_rate)
        return n * sum(frame_bits(8, extended_id=f.extended, worst_case=worst_case) for f in self.frames)


EXAMPLE_LAYOUT = """
rate = 500.0
[[frames]]   # orientation, Q15 (1/32768)
id = 0x50
fields = [{ name = "qw", byte = 0, type = "i16", scale = 3.0517578125e-05 },
          { name = "qx", byte = 2, type = "i16", scale = 3.0517578125e-05 },
          { name = "qy", byte = 4, type = "i16", scale = 3.0517578125e-05 },
          { name = "qz", byte = 6, type = "i16", scale = 3.0517578125e-05 }]
[[frames]]   # rate of turn, +-2000 deg/s full scale, and a 1 ms tick counter
id = 0x51
fields = [{ name = "gx", byte = 0, type = "i16", scale = 0.0010652644360316954 },
          { name = "gy", byte = 2, type = "i16", scale = 0.0010652644360316954 },
          { name = "gz", byte = 4, type = "i16", scale = 0.0010652644360316954 },
          { name = "time", byte = 6, type = "u16", scale = 0.001 }]
[[frames]]   # specific force, +-16 g full scale
id = 0x52
fields = [{ name = "ax", byte = 0, type = "i16", scale = 0.0047884033203125 },
          { name = "ay", byte = 2, type = "i16", scale = 0.0047884033203125 },
          { name = "az", byte = 4, type = "i16", scale = 0.0047884033203125 }]
"""
"""A generic layout (little-endian 16-bit fields in three frames), the one ``giwbc deploy --emulate
--imu can`` rehearses with; a real IMU's manual gives its own ids, offsets and scales."""


def example_layout() -> CanImuLayout:
    """:data:`EXAMPLE_LAYOUT`, parsed."""
    return parse_can_imu_layout(tomllib.loads(EXAMPLE_LAYOUT), "giwbc.hal.can_imu.EXAMPLE_LAYOUT")


# ----------------------------------------------------------------------------- configuration
def _fail(source: str, msg: str) -> HardwareConfigError:
    """The error for ``msg`` in the plan's ``[imu]`` table (the hardware plan's TOML place)."""
    return TomlPlace(f"{source}: imu", HardwareConfigError).fail(msg)  # type: ignore[return-value]


def _number(source: str, where: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise _fail(source, f"{where}: expected a finite number, got {v!r}")
    return float(v)


def _endian(source: str, where: str, v: Any) -> str:
    if v not in ("little", "big"):
        raise _fail(source, f"{where}: endian must be 'little' or 'big', got {v!r}")
    return "<" if v == "little" else ">"


def parse_can_imu_layout(table: Mapping[str, Any], source: str = "<hardware.toml>") -> CanImuLayout:
    """The layout from an ``[imu]`` table (``rate`` and ``[[imu.frames]]``); HardwareConfigError
    naming the frame and field for anything missing, unknown, overlapping or out of a frame."""
    rate = _number(source, "rate", table.get("rate", float("nan")))
    if rate <= 0:
        raise _fail(source, f"rate must be > 0 Hz, got {rate}")
    raw_frames = table.get("frames")
    if not isinstance(raw_frames, list) or not raw_frames:
        raise _fail(source, "a CAN IMU needs [[imu.frames]] tables (id and fields of each frame it sends)")
    frames: list[ImuFrame] = []
    seen: dict[str, str] = {}
    for k, fr in enumerate(raw_frames):
        where = f"frames[{k}]"
        if not isinstance(fr, Mapping):
            raise _fail(source, f"{where}: expected a table")
        unknown = sorted(set(fr) - _FRAME_KEYS)
        if unknown or "id" not in fr or "fields" not in fr:
            raise _fail(source, f"{where}: keys {sorted(_FRAME_KEYS)} (id and fields required), got {sorted(fr)}")
        extended = fr.get("extended", False)
        if not isinstance(extended, bool):
            raise _fail(source, f"{where}: extended must be true or false")
        can_id = fr["id"]
        limit = CAN_EFF_MASK if extended else CAN_SFF_MASK
        if isinstance(can_id, bool) or not isinstance(can_id, int) or not 0 <= can_id <= limit:
            raise _fail(source, f"{where}: id must be an integer in 0..0x{limit:X}, got {can_id!r}")
        if any(f.can_id == can_id and f.extended == extended for f in frames):
            raise _fail(source, f"{where}: duplicate frame id 0x{can_id:X}")
        where = f"frame 0x{can_id:X}"
        endian = _endian(source, where, fr.get("endian", "little"))
        if not isinstance(fr["fields"], list) or not fr["fields"]:
            raise _fail(source, f"{where}: fields must be a non-empty array of tables")
        fields: list[ImuField] = []
        for j, f in enumerate(fr["fields"]):
            fw = f"{where} fields[{j}]"
            if not isinstance(f, Mapping):
                raise _fail(source, f"{fw}: expected a table")
            unknown = sorted(set(f) - _FIELD_KEYS)
            missing = [x for x in ("name", "byte", "type") if x not in f]
            if unknown or missing:
                raise _fail(source, f"{fw}: unknown key(s) {unknown}, missing {missing}; allowed {sorted(_FIELD_KEYS)}")
            name = f["name"]
            if name not in FIELD_NAMES:
                raise _fail(source, f"{fw}: name must be one of {', '.join(FIELD_NAMES)}, got {name!r}")
            if name in seen:
                raise _fail(source, f"{fw}: {name!r} already comes from {seen[name]}")
            seen[name] = where
            if f["type"] not in FIELD_TYPES:
                raise _fail(source, f"{fw}: type must be one of {', '.join(FIELD_TYPES)}, got {f['type']!r}")
            byte = f["byte"]
            if isinstance(byte, bool) or not isinstance(byte, int) or byte < 0:
                raise _fail(source, f"{fw}: byte must be an integer >= 0, got {byte!r}")
            e = _endian(source, fw, f["endian"]) if "endian" in f else endian
            dtype = np.dtype(e + FIELD_TYPES[f["type"]])
            scale = _number(source, f"{fw} scale", f.get("scale", 1.0))
            if scale == 0:
                raise _fail(source, f"{fw}: scale must not be 0")
            new = ImuField(name, byte, dtype, scale, _number(source, f"{fw} bias", f.get("bias", 0.0)))
            if new.end > 8:
                raise _fail(source, f"{fw}: {name!r} ends at byte {new.end}, past the 8 bytes of a classic CAN frame")
            clash = next((o for o in fields if o.byte < new.end and new.byte < o.end), None)
            if clash is not None:
                raise _fail(source, f"{fw}: {name!r} overlaps {clash.name!r}")
            fields.append(new)
        frames.append(ImuFrame(can_id, extended, tuple(fields)))
    has = set(seen)
    quat, euler = has & set(QUATERNION), has & set(EULER)
    problems = []
    if quat and euler:
        problems.append("orientation from both a quaternion and Euler angles")
    elif quat != set(QUATERNION) and euler != set(EULER):
        problems.append(f"orientation needs all of {QUATERNION} or all of {EULER}")
    for group in (GYRO, ACCEL):
        if not set(group) <= has:
            problems.append(f"missing {sorted(set(group) - has)}")
    if problems:
        raise _fail(source, "; ".join(problems))
    return CanImuLayout(tuple(frames), rate)


# ----------------------------------------------------------------------------- decoding
@dataclass
class CanImuCounters:
    frames: int = 0  # IMU frames taken
    samples: int = 0
    short_frames: int = 0  # shorter than the layout needs: ignored
    incomplete: int = 0  # partial samples dropped (a frame came twice before the others)

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass
class CanImu:
    """Assembles IMU samples from CAN frames; an :class:`~giwbc.hal.can_robot.ImuSource`.

    The owner of the bus hands it the frames it receives (:meth:`take` on a batch of
    :data:`~giwbc.hal.frames.FRAME` records, or :meth:`feed` per frame); :meth:`read` returns the
    newest complete sample (the same object until a new one completes)."""

    layout: CanImuLayout
    clock: Callable[[], float] = time.monotonic
    bus: str | None = None  # the plan's bus the frames come on (for the robot that routes them)
    counters: CanImuCounters = field(default_factory=CanImuCounters)
    _values: dict[str, float] = field(default_factory=dict)
    _got: set[int] = field(default_factory=set)
    _latest: ImuReading | None = None
    _last_time_raw: float | None = None
    _time_offset: float = 0.0

    def __post_init__(self) -> None:
        self._by_wire = {f.wire_id: f for f in self.layout.frames}
        self._wire_ids = np.array(sorted(self._by_wire), dtype=np.uint32)
        tf = next((f for fr in self.layout.frames for f in fr.fields if f.name == "time"), None)
        self._time_span = None
        if tf is not None and tf.dtype.kind == "u":
            self._time_span = float(2 ** (8 * tf.dtype.itemsize)) * tf.scale

    def read(self) -> ImuReading | None:
        return self._latest

    def take(self, batch: np.ndarray, now: float | None = None) -> np.ndarray:
        """Feed the IMU's frames of ``batch`` (in order); the mask of the rows that were IMU frames
        (the caller drops them before decoding motor replies)."""
        ids = batch["can_id"] & np.uint32(~(CAN_RTR_FLAG | CAN_ERR_FLAG) & 0xFFFFFFFF)
        mask = np.isin(ids, self._wire_ids) & ((batch["can_id"] & np.uint32(CAN_RTR_FLAG | CAN_ERR_FLAG)) == 0)
        for k in np.flatnonzero(mask):
            self.feed(int(ids[k]), batch["data"][k, : batch["len"][k]].tobytes(), now)
        return mask

    def feed(self, wire_id: int, payload: bytes, now: float | None = None) -> bool:
        """One frame (``wire_id`` with the EFF flag for extended ids); True when it completed a sample."""
        frame = self._by_wire.get(wire_id)
        if frame is None:
            return False
        c = self.counters
        c.frames += 1
        if len(payload) < frame.length:
            c.short_frames += 1
            return False
        if frame.can_id in self._got:
            c.incomplete += 1
            self._got.clear()
        self._got.add(frame.can_id)
        for f in frame.fields:
            self._values[f.name] = f.decode(payload)
        if len(self._got) < len(self.layout.frames):
            return False
        self._got.clear()
        self._latest = self._reading(self.clock() if now is None else now)
        c.samples += 1
        return True

    def _reading(self, now: float) -> ImuReading:
        v = self._values
        if self.layout.euler:
            q = rpy_to_quat(v["roll"], v["pitch"], v["yaw"])
        else:
            q = np.array([v["qx"], v["qy"], v["qz"], v["qw"]])
            n = float(np.linalg.norm(q))
            q = q / n if n > 0 else np.full(4, np.nan)  # scaled integers are not exactly unit
        t = now
        if "time" in v:
            raw = v["time"]
            if self._time_span is not None and self._last_time_raw is not None and raw < self._last_time_raw - 0.5 * self._time_span:
                self._time_offset += self._time_span
            self._last_time_raw = raw
            t = raw + self._time_offset
        return ImuReading(q, np.array([v["gx"], v["gy"], v["gz"]]), np.array([v["ax"], v["ay"], v["az"]]), t)


class CanImuEncoder:
    """The frames the IMU of ``layout`` sends for one :class:`ImuReading` (for the emulator and
    tests); ``clamped`` counts values outside a field's range."""

    def __init__(self, layout: CanImuLayout) -> None:
        self.layout = layout
        self.clamped = 0

    def values(self, reading: ImuReading) -> dict[str, float]:
        x, y, z, w = (float(a) for a in reading.quaternion)
        out = dict(zip(GYRO, map(float, reading.angular_velocity)))
        out.update(zip(ACCEL, map(float, reading.linear_acceleration)))
        if self.layout.euler:
            out.update(zip(EULER, quat_to_rpy((x, y, z, w))))
        else:
            out.update(qx=x, qy=y, qz=z, qw=w)
        out["time"] = float(reading.time)
        return out

    def encode(self, reading: ImuReading) -> np.ndarray:
        """A batch of :data:`FRAME` records, one per configured frame, in layout order."""
        values = self.values(reading)
        out = np.zeros(len(self.layout.frames), dtype=FRAME)
        for k, fr in enumerate(self.layout.frames):
            payload = bytearray(8)
            for f in fr.fields:
                value = values[f.name]
                if f.name == "time" and f.dtype.kind == "u":  # a counter: wraps like the device's
                    value = math.fmod(value - f.bias, float(2 ** (8 * f.dtype.itemsize)) * f.scale) + f.bias
                self.clamped += f.encode(value, payload)
            out[k]["can_id"] = fr.wire_id
            out[k]["len"] = 8
            out[k]["data"] = np.frombuffer(bytes(payload), dtype=np.uint8)
        return out


__all__ = [
    "EXAMPLE_LAYOUT",
    "example_layout",
    "CanImu",
    "CanImuCounters",
    "CanImuEncoder",
    "CanImuLayout",
    "FIELD_NAMES",
    "FIELD_TYPES",
    "ImuField",
    "ImuFrame",
    "parse_can_imu_layout",
]
