"""The motors' side of the CAN buses, emulated: MuJoCo physics behind MIT-mode firmware.

:class:`ActuatorEmulator` (lockstep with the host, :mod:`~giwbc.emulation.emulator`) or
:class:`EmulatorProcess` (its own process and clock, :mod:`~giwbc.emulation.process`) answer a
hardware plan's frames as real motors would; :mod:`~giwbc.emulation.faults` injects faults,
:mod:`~giwbc.emulation.thermal` heats the coils, :mod:`~giwbc.emulation.firmware` is the
vectorized firmware codec. It sits above the HAL (it speaks the HAL's plans and protocols) and
below the runtimes and applications that drive it.
"""

from giwbc.emulation.config import AppliedSnapshot, EmulatorConfig, EmulatorCounters, Gantry
from giwbc.emulation.emulator import ActuatorEmulator
from giwbc.emulation.faults import EMULATOR_FAULT_KINDS, FAULT_KINDS, HOST_FAULT_KINDS, FaultInjection
from giwbc.emulation.firmware import MOTOR, OFF, OVER_CURRENT, OVER_TEMPERATURE
from giwbc.emulation.process import EmulatorProcess, SharedImuChannel
from giwbc.emulation.thermal import ThermalModel

__all__ = [
    "EMULATOR_FAULT_KINDS",
    "FAULT_KINDS",
    "HOST_FAULT_KINDS",
    "MOTOR",
    "OFF",
    "OVER_CURRENT",
    "OVER_TEMPERATURE",
    "ActuatorEmulator",
    "AppliedSnapshot",
    "EmulatorConfig",
    "EmulatorCounters",
    "EmulatorProcess",
    "FaultInjection",
    "Gantry",
    "SharedImuChannel",
    "ThermalModel",
]
