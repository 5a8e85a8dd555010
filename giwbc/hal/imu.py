"""Where the host's IMU samples come from: an :class:`ImuSource`, chosen from the plan's IMU
configuration by :func:`imu_source_for`. :class:`ImuChannel` is the in-process mailbox the actuator
emulator publishes to (the ``emulated`` IMU); both the host side (:mod:`giwbc.hal.can_robot`) and
the motor side (:mod:`giwbc.emulation`) use it."""

from __future__ import annotations

from typing import Protocol

from giwbc.hal.hardware import ImuConfig
from giwbc.robot.interface import ImuReading


class ImuSource(Protocol):
    """Where IMU samples come from: ``read()`` returns the newest sample (None before the first)."""

    def read(self) -> ImuReading | None: ...


class ImuChannel:
    """In-process mailbox for IMU samples: a producer (the emulator) publishes, the robot reads."""

    def __init__(self) -> None:
        self._latest: ImuReading | None = None
        self.published = 0

    def publish(self, reading: ImuReading) -> None:
        self._latest = reading
        self.published += 1

    def read(self) -> ImuReading | None:
        return self._latest


def imu_source_for(config: ImuConfig, channel: ImuChannel | None = None) -> ImuSource:
    """The IMU source a plan asks for. ``emulated`` needs the emulator's channel; ``serial`` and
    ``can`` IMUs have no driver yet and raise ``NotImplementedError`` naming what is missing."""
    if config.source == "emulated":
        if channel is None:
            raise ValueError("the hardware plan's IMU is 'emulated': it exists only with the actuator emulator (--emulate)")
        return channel
    where = config.device if config.source == "serial" else f"bus {config.bus} id 0x{config.can_id or 0:X}"
    raise NotImplementedError(f"no driver for a {config.source!r} IMU ({where}) yet; use an emulated IMU")


__all__ = ["ImuChannel", "ImuSource", "imu_source_for"]
