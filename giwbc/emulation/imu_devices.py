"""Emulated IMU devices: the emulator's IMU samples as the bytes a real IMU would send, so the host
reads them through its real drivers.

- :class:`SerialImuDevice`: an Xsens MTi (MTData2 messages, :mod:`giwbc.hal.xsens`) on a
  pseudo-terminal; the host opens :attr:`SerialImuDevice.path` with pyserial like a USB serial
  adapter.
- :class:`CanImuDevice`: the frames of a configured CAN IMU (:mod:`giwbc.hal.can_imu`) on the
  emulator's end of the IMU's bus, next to the motors' replies.

:func:`imu_device_for` picks one from the plan's ``[imu]`` (None for the ``emulated`` IMU, which
stays the in-process channel).
"""

from __future__ import annotations

import os
import pty
import select
import time
import tty
from collections.abc import Mapping

from giwbc.hal.can_imu import CanImuEncoder
from giwbc.hal.frames import FramePort
from giwbc.hal.hardware import ImuConfig
from giwbc.hal.xsens import encode_mtdata2, sample_of_reading
from giwbc.robot.interface import ImuReading


class SerialImuDevice:
    """An MTi writing one MTData2 message per sample to a pseudo-terminal (raw mode). Writes never
    block: a sample that does not fit (the host is not reading) is dropped and counted.

    A pty hands written bytes to its reading side from a kernel worker, a little later; in
    lockstep the host reads within microseconds, so each write waits (``settle`` s at most) until
    the bytes are readable: the sample published at a cycle is the one the host reads at it, as
    on a serial line whose latency is below one period."""

    def __init__(self, settle: float = 0.05) -> None:
        self.settle = settle
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)  # no line discipline: the bytes pass as they are
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self.counter = 0
        self.written = 0
        self.dropped = 0

    def publish(self, reading: ImuReading) -> None:
        data = encode_mtdata2(sample_of_reading(reading, self.counter))
        self.counter += 1
        try:
            n = os.write(self._master, data)
        except BlockingIOError:
            n = 0
        if n == len(data):
            self.written += 1
            select.select([self._slave], [], [], self.settle)
        else:
            self.dropped += 1  # a torn message: the host's parser resynchronises on the next

    def close(self) -> None:
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass


class CanImuDevice:
    """A CAN IMU sending its configured frames on a bus port once per sample."""

    def __init__(self, config: ImuConfig, port: FramePort) -> None:
        assert config.layout is not None
        self.encoder = CanImuEncoder(config.layout)
        self.port = port
        self.sent = 0
        self.dropped = 0

    def publish(self, reading: ImuReading) -> None:
        outcome = self.port.send(self.encoder.encode(reading), time.perf_counter() + 0.05)  # never the subject of timing
        self.sent += outcome.sent
        self.dropped += outcome.dropped

    def close(self) -> None:
        """The port belongs to the emulator's bus: nothing to release here."""


def imu_device_for(config: ImuConfig, ports: Mapping[str, FramePort]) -> SerialImuDevice | CanImuDevice | None:
    """The emulated device for the plan's IMU (``ports``: the emulator's ports by bus name)."""
    if config.source == "serial":
        return SerialImuDevice()
    if config.source == "can":
        return CanImuDevice(config, ports[config.bus])  # type: ignore[index]
    return None


__all__ = ["CanImuDevice", "SerialImuDevice", "imu_device_for"]
