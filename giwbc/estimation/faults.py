"""Sensor faults the estimator detects: flags, a human-readable reason each, and running counters.

Bad data is never used silently: every update returns a :class:`FaultReport` (flags of this update,
one reason per flag, whether the estimate was held) and :class:`FaultMonitor` counts every fault
since the estimator started.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

__all__ = ["HOLDING_FAULTS", "Fault", "FaultMonitor", "FaultReport"]


class Fault(enum.IntFlag):
    """What went wrong with one measurement."""

    NONE = 0
    TIME_INVALID = enum.auto()  # the IMU timestamp is NaN or infinite: update skipped
    STALE_TIMESTAMP = enum.auto()  # the IMU timestamp repeats the last accepted one: update skipped
    TIME_BACKWARDS = enum.auto()  # the IMU timestamp is older than the last accepted one: update skipped
    TIME_GAP = enum.auto()  # longer than max_dt since the last accepted sample: integrated, flagged
    GYRO_INVALID = enum.auto()  # NaN/inf angular velocity: update skipped
    GYRO_SATURATED = enum.auto()  # angular velocity at the gyro's range: update skipped
    ACCEL_INVALID = enum.auto()  # NaN/inf specific force: predict without it
    ACCEL_SATURATED = enum.auto()  # specific force at the accelerometer's range: predict without it
    ORIENTATION_INVALID = enum.auto()  # the IMU's own orientation is NaN or not a unit quaternion: not used
    JOINT_POSITION_INVALID = enum.auto()  # NaN/inf encoder position: last good value held, no leg kinematics
    JOINT_VELOCITY_INVALID = enum.auto()  # NaN/inf encoder velocity: last good value held, no leg velocity
    JOINT_EFFORT_INVALID = enum.auto()  # NaN/inf effort: contact flags held
    CONTACT_FORCE_INVALID = enum.auto()  # NaN/inf measured contact force: contact flags held
    NO_STANCE_FOOT = enum.auto()  # no foot in contact: base velocity from the IMU alone (drifts)


# Faults after which the estimate is not updated at all (the last good one is held).
HOLDING_FAULTS = Fault.TIME_INVALID | Fault.STALE_TIMESTAMP | Fault.TIME_BACKWARDS | Fault.GYRO_INVALID | Fault.GYRO_SATURATED


@dataclass(frozen=True)
class FaultReport:
    """Faults found in one update: ``flags``, one ``reasons`` line per fault, and ``held``: the
    estimate was not updated and is the last good one."""

    flags: Fault = Fault.NONE
    reasons: tuple[str, ...] = ()
    held: bool = False

    @property
    def ok(self) -> bool:
        return self.flags == Fault.NONE


class FaultMonitor:
    """Collects the faults of one update and counts them over the estimator's life."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {fault.name: 0 for fault in Fault if fault != Fault.NONE}
        self.total = 0
        self.consecutive_held = 0
        self._bits = 0  # flags of the current update as a plain int: enum operators are slow
        self._reasons: list[str] = []

    def flag(self, fault: Fault, reason: str) -> None:
        """Record ``fault`` for the current update (once per update)."""
        bit = int(fault)
        if self._bits & bit:
            return
        self._bits |= bit
        self._reasons.append(f"{fault.name}: {reason}")
        self.counts[fault.name] += 1
        self.total += 1

    def has(self, faults: int) -> bool:
        """Whether any of ``faults`` (a Fault or an int of Fault bits) was flagged in this update."""
        return bool(self._bits & faults)

    def finish(self, held: bool = False) -> FaultReport:
        """The report of the current update (``held``: the estimate was not updated, which any
        holding fault implies); the monitor is ready for the next one."""
        held = held or bool(self._bits & _HOLDING_BITS)
        self.consecutive_held = self.consecutive_held + 1 if held else 0
        if not self._bits and not held:
            return _NO_FAULT
        report = FaultReport(Fault(self._bits), tuple(self._reasons), held)
        self._bits, self._reasons = 0, []
        return report


_HOLDING_BITS = int(HOLDING_FAULTS)
_NO_FAULT = FaultReport()
