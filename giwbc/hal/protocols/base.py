"""What every actuator protocol provides: command encoding, special frames, total reply decoding.

A protocol instance is built for the motors of one bus (it needs them to demultiplex replies).
Values crossing this interface are motor side (see :mod:`giwbc.hal.motor`); the
:class:`~giwbc.hal.motor.MotorGroup` of the protocol converts from and to joint side.

Decoding is *total*: for any input, :meth:`ActuatorProtocol.decode` returns a :class:`MotorReply`
or raises a :class:`CanProtocolError` subclass, never anything else, so a bus loop can catch one
exception type and count it.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from giwbc.hal.motor import RANGE_FIELDS, MotorConfig, MotorGroup
from giwbc.errors import (
    CanProtocolError,
    CommandValueError,
    CorruptFrameError,
    FrameLengthError,
    ProtocolConfigError,
    UnknownMotorError,
)
from giwbc.hal.frames import CAN_EFF_MASK, fields


@dataclass(frozen=True, slots=True)
class CanFrame:
    """One classic CAN data frame, independent of python-can."""

    arbitration_id: int
    data: bytes
    is_extended_id: bool = False


@dataclass(frozen=True, slots=True)
class MotorReply:
    """A decoded reply, motor side. Optional fields are None when the variant does not carry them.

    ``temperature`` is the driver/motor temperature the variant reports (°C; Damiao: MOS),
    ``rotor_temperature`` the coil temperature where reported, ``error_code`` 0 means no fault,
    ``status`` is a raw status field (Damiao's state nibble).
    """

    motor_id: int
    position: float
    velocity: float
    torque: float
    temperature: float | None = None
    rotor_temperature: float | None = None
    error_code: int | None = None
    voltage: float | None = None
    status: int | None = None

    @property
    def faulted(self) -> bool:
        """The motor reported a fault."""
        return bool(self.error_code)


REPLY, UNKNOWN, CORRUPT, ERROR_FRAME = 0, 1, 2, 3
"""Verdicts of :meth:`ActuatorProtocol.decode_frames` per frame: a valid reply; not from a
configured motor (:class:`UnknownMotorError`, remote frames); addressed like a reply but
undecodable (any other :class:`CanProtocolError`); a CAN error frame."""


@dataclass(frozen=True, slots=True)
class DecodedReplies:
    """A batch of frames decoded as replies, one row per frame (see :data:`REPLY` for ``verdict``).

    ``index`` is the motor's position in the decoder's motor order and ``motor_id`` its CAN id
    (both -1 where the row is not a reply). ``state`` holds position, velocity and torque, motor
    side, one row per frame. Optional fields are NaN (floats) or -1 (integers) where the motor's
    reply variant does not report them or the row is no reply.
    """

    verdict: NDArray[np.int64]
    index: NDArray[np.int64]
    motor_id: NDArray[np.int64]
    state: NDArray[np.float64]  # (M, 3): position, velocity, torque
    temperature: NDArray[np.float64]
    rotor_temperature: NDArray[np.float64]
    error_code: NDArray[np.int64]
    voltage: NDArray[np.float64]
    status: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.verdict.shape[0])

    @property
    def position(self) -> NDArray[np.float64]:
        return self.state[:, 0]

    @property
    def velocity(self) -> NDArray[np.float64]:
        return self.state[:, 1]

    @property
    def torque(self) -> NDArray[np.float64]:
        return self.state[:, 2]

    @property
    def valid(self) -> NDArray[np.bool_]:
        return self.verdict == REPLY

    def count(self, verdict: int) -> int:
        return int(np.count_nonzero(self.verdict == verdict))

    def reply(self, k: int) -> MotorReply | None:
        """Row ``k`` as a :class:`MotorReply` (what :meth:`ActuatorProtocol.decode` returns), or None."""
        if self.verdict[k] != REPLY:
            return None

        def opt(x: float) -> float | None:
            return None if x != x else float(x)

        def opt_int(x: int) -> int | None:
            return None if x < 0 else int(x)

        return MotorReply(
            int(self.motor_id[k]), float(self.position[k]), float(self.velocity[k]), float(self.torque[k]),
            opt(self.temperature[k]), opt(self.rotor_temperature[k]), opt_int(self.error_code[k]),
            opt(self.voltage[k]), opt_int(self.status[k]),
        )  # fmt: skip

    @classmethod
    def from_replies(cls, verdict: Sequence[int], index: Sequence[int], replies: Sequence[MotorReply | None]) -> DecodedReplies:
        """Rows from per-frame results (the reference path: one :meth:`ActuatorProtocol.decode` each)."""

        def column(name: str, missing: float) -> list[float]:
            return [missing if r is None or getattr(r, name) is None else getattr(r, name) for r in replies]

        nan = math.nan
        return cls(
            np.asarray(verdict, dtype=np.int64).reshape(-1),
            np.asarray(index, dtype=np.int64).reshape(-1),
            np.array([-1 if r is None else r.motor_id for r in replies], dtype=np.int64),
            np.array([column("position", nan), column("velocity", nan), column("torque", nan)], dtype=float).reshape(3, -1).T.copy(),
            np.array(column("temperature", nan), dtype=float),
            np.array(column("rotor_temperature", nan), dtype=float),
            np.array(column("error_code", -1), dtype=np.int64),
            np.array(column("voltage", nan), dtype=float),
            np.array(column("status", -1), dtype=np.int64),
        )

    def take(self, rows: Any) -> DecodedReplies:
        """The rows ``rows`` (an index array or mask), in that order."""
        return DecodedReplies(*(getattr(self, name)[rows] for name in self.__slots__))

    @classmethod
    def concatenate(cls, parts: Sequence[DecodedReplies], offsets: Sequence[int] = ()) -> DecodedReplies:
        """Rows of several batches in order; ``offsets`` are added to each part's valid indexes."""
        if not parts:
            return cls.from_replies([], [], [])
        offsets = list(offsets) or [0] * len(parts)
        index = np.concatenate([np.where(p.index >= 0, p.index + o, -1) for p, o in zip(parts, offsets)])
        rest = {name: np.concatenate([getattr(p, name) for p in parts]) for name in cls.__slots__ if name != "index"}
        return cls(index=index, **rest)


@dataclass(frozen=True, slots=True)
class MotorCommand:
    """A decoded command frame, motor side (what an actuator, or its emulator, receives).

    ``special`` names a special frame (``"enter"``, ``"exit"``, ``"zero"``, ``"clear"``); the
    values are then NaN.
    """

    motor_id: int
    position: float
    velocity: float
    kp: float
    kd: float
    torque: float
    special: str | None = None


@dataclass(frozen=True, slots=True)
class EncodedCommand:
    """One command frame and which fields were clamped on the host (wire order: position, velocity,
    kp, kd, torque)."""

    frame: CanFrame
    clamped: tuple[bool, bool, bool, bool, bool]

    @property
    def clamped_fields(self) -> tuple[str, ...]:
        return tuple(name for name, c in zip(RANGE_FIELDS, self.clamped) if c)


@dataclass(frozen=True, slots=True)
class CommandBatch:
    """Command frames for every motor of a protocol instance, in its motor order.

    ``data`` is (N, 8) uint8, ``clamped`` (N, 5) bool (which fields were clamped on the host).
    """

    arbitration_ids: NDArray[np.int64]
    data: NDArray[np.uint8]
    clamped: NDArray[np.bool_]
    is_extended_id: bool = False

    def __len__(self) -> int:
        return int(self.data.shape[0])

    @property
    def clamp_count(self) -> int:
        """How many fields were clamped in all."""
        return int(np.count_nonzero(self.clamped))

    def frames(self) -> list[CanFrame]:
        raw = self.data.tobytes()
        w = self.data.shape[1] if self.data.ndim == 2 else 0
        ext = self.is_extended_id
        return [
            CanFrame(int(a), raw[i * w : (i + 1) * w], ext) for i, a in enumerate(self.arbitration_ids.tolist())
        ]


@dataclass(frozen=True, slots=True)
class FrameTraffic:
    """Per motor and control cycle: payload bytes of the command and of the reply (for bus load)."""

    command_bytes: int
    reply_bytes: int
    extended_id: bool = False


class ActuatorProtocol(ABC):
    """An actuator protocol bound to the motors of one bus."""

    name: ClassVar[str]
    reply_variants: ClassVar[tuple[str, ...]]

    def __init__(self, motors: Sequence[MotorConfig]) -> None:
        self.motors: tuple[MotorConfig, ...] = tuple(motors)
        self.group = MotorGroup(self.motors)
        ids = [m.can_id for m in self.motors]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ProtocolConfigError(f"duplicate motor CAN id(s) {dup}")
        self.index: dict[int, int] = {m.can_id: i for i, m in enumerate(self.motors)}

    def motor(self, motor_id: int) -> MotorConfig:
        try:
            return self.motors[self.index[motor_id]]
        except KeyError:
            raise UnknownMotorError(f"no motor with id {motor_id} on this bus") from None

    @classmethod
    @abstractmethod
    def traffic(cls, motor: MotorConfig) -> FrameTraffic:
        """Frames per control cycle for ``motor`` (one command, one reply)."""

    @abstractmethod
    def encode_command(
        self, motor_id: int, position: float, velocity: float, kp: float, kd: float, torque: float
    ) -> EncodedCommand:
        """One command frame (motor side values), clamped to the motor's ranges."""

    @abstractmethod
    def encode_commands(
        self, position: ArrayLike, velocity: ArrayLike, kp: ArrayLike, kd: ArrayLike, torque: ArrayLike
    ) -> CommandBatch:
        """Command frames for all motors at once (arrays in motor order; scalars broadcast)."""

    @abstractmethod
    def enter_motor_mode(self, motor_id: int) -> CanFrame:
        """Frame that enables the motor."""

    @abstractmethod
    def exit_motor_mode(self, motor_id: int) -> CanFrame:
        """Frame that disables the motor."""

    @abstractmethod
    def set_zero(self, motor_id: int) -> CanFrame:
        """Frame that makes the motor's present position its zero."""

    @abstractmethod
    def decode(self, arbitration_id: Any, data: Any, is_extended_id: bool = False) -> MotorReply:
        """A reply, or a :class:`CanProtocolError` subclass; never another exception."""

    def decode_frames(self, batch: NDArray[Any]) -> DecodedReplies:
        """Decode a batch of :data:`~giwbc.hal.frames.FRAME` records at once (error frames get
        :data:`ERROR_FRAME`, remote frames :data:`UNKNOWN`). This default calls :meth:`decode`
        per frame; a protocol may vectorize it, with exactly the same results."""
        f = fields(batch)
        raw_ids = (batch["can_id"] & CAN_EFF_MASK).tolist()  # a standard frame's junk id bits stay: decode() rejects them
        verdicts, indexes, replies = [], [], []
        for k in range(len(batch)):
            reply, verdict = None, UNKNOWN
            if f.error[k]:
                verdict = ERROR_FRAME
            elif not f.remote[k]:
                length = int(f.length[k])
                data = batch[k]["data"].tobytes()
                data = data[:length] if length <= 8 else data + bytes(length - 8)  # a longer frame keeps its length
                try:
                    reply, verdict = self.decode(raw_ids[k], data, bool(f.extended[k])), REPLY
                except UnknownMotorError:
                    verdict = UNKNOWN
                except CanProtocolError:
                    verdict = CORRUPT
            verdicts.append(verdict)
            indexes.append(-1 if reply is None else self.index[reply.motor_id])
            replies.append(reply)
        return DecodedReplies.from_replies(verdicts, indexes, replies)

    @abstractmethod
    def decode_command(self, arbitration_id: Any, data: Any, is_extended_id: bool = False) -> MotorCommand:
        """A command or special frame as the motor sees it; :class:`CanProtocolError` otherwise."""

    @abstractmethod
    def encode_reply(self, motor_id: int, position: float, velocity: float, torque: float, **extra: Any) -> CanFrame:
        """A reply frame as ``motor_id`` would send it (for emulators and tests)."""
