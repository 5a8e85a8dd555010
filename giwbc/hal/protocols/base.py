"""What every actuator protocol provides: command encoding, special frames, total reply decoding.

A protocol instance is built for the motors of one bus (it needs them to demultiplex replies).
Values crossing this interface are motor side (see :mod:`giwbc.hal.motor`); the
:class:`~giwbc.hal.motor.MotorGroup` of the protocol converts from and to joint side.

Decoding is *total*: for any input, :meth:`ActuatorProtocol.decode` returns a :class:`MotorReply`
or raises a :class:`CanProtocolError` subclass, never anything else, so a bus loop can catch one
exception type and count it.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from giwbc.hal.motor import RANGE_FIELDS, MotorConfig, MotorGroup


class CanProtocolError(Exception):
    """A received frame is not a valid reply from a configured motor."""


class FrameLengthError(CanProtocolError):
    """The frame's payload length fits no reply variant expected for it."""


class UnknownMotorError(CanProtocolError):
    """The frame is not addressed from a motor configured on this bus (unknown id, foreign frame)."""


class CorruptFrameError(CanProtocolError):
    """The frame is addressed correctly but its content cannot be a reply (or the input is not bytes)."""


class ProtocolConfigError(ValueError):
    """The motors given to a protocol cannot work together (bad id, ambiguous replies, bad variant)."""


class CommandValueError(ValueError):
    """A command cannot be encoded at all (NaN); out-of-range values are clamped instead."""


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

    @abstractmethod
    def decode_command(self, arbitration_id: Any, data: Any, is_extended_id: bool = False) -> MotorCommand:
        """A command or special frame as the motor sees it; :class:`CanProtocolError` otherwise."""

    @abstractmethod
    def encode_reply(self, motor_id: int, position: float, velocity: float, torque: float, **extra: Any) -> CanFrame:
        """A reply frame as ``motor_id`` would send it (for emulators and tests)."""
