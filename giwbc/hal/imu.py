"""Where the host's IMU samples come from: an :class:`ImuSource`, chosen from the plan's IMU
configuration by :func:`imu_source_for`: the emulator's in-process :class:`ImuChannel`
(``emulated``), an Xsens MTi on a serial device (``serial``, :mod:`giwbc.hal.xsens`), or frames on
one of the plan's CAN buses (``can``, :mod:`giwbc.hal.can_imu`: the :class:`~giwbc.hal.can_robot.CanRobot`
hands the IMU's frames to it as it reads its buses). :class:`ImuChannel` is the in-process mailbox
the actuator emulator publishes to; both the host side and the motor side (:mod:`giwbc.emulation`)
use it."""

from __future__ import annotations

from typing import Protocol

from giwbc.errors import HardwareConfigError
from giwbc.hal.can_imu import CanImu, example_layout
from giwbc.hal.hardware import HardwarePlan, ImuConfig
from giwbc.hal.xsens import open_serial_imu
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
    """The IMU source a plan asks for. ``emulated`` needs the emulator's channel (ValueError
    without); ``serial`` opens the device (HardwareConfigError when it cannot); ``can`` returns the
    :class:`CanImu` the robot feeds."""
    if config.source == "emulated":
        if channel is None:
            raise ValueError("the hardware plan's IMU is 'emulated': it exists only with the actuator emulator (--emulate)")
        return channel
    if config.source == "serial":
        assert config.device is not None
        return open_serial_imu(config.device, config.baudrate)
    if config.source == "can" and config.layout is not None:
        return CanImu(config.layout, bus=config.bus)
    raise HardwareConfigError(f"IMU source {config.source!r} without its settings")


def rehearsal_imu(plan: HardwarePlan, source: str) -> ImuConfig:
    """The IMU a rehearsal (``giwbc deploy --emulate --imu SOURCE``) runs with: the plan's own when it
    is of that source; else a serial MTi (the emulator supplies the device) or a CAN IMU of
    :data:`~giwbc.hal.can_imu.EXAMPLE_LAYOUT` on the plan's least loaded bus."""
    if source == plan.imu.source:
        return plan.imu
    if source == "emulated":
        return ImuConfig("emulated")
    if source == "serial":
        return ImuConfig("serial", device="(the emulator's pseudo-terminal)", baudrate=921600)
    if source == "can":
        bus = min(plan.buses, key=lambda b: plan.loads[b.name].bits_nominal / b.bitrate).name
        return ImuConfig("can", bus=bus, layout=example_layout())
    raise ValueError(f"IMU source must be emulated, serial or can, got {source!r}")


__all__ = [
    "rehearsal_imu","ImuChannel", "ImuSource", "imu_source_for"]
