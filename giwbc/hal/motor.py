"""Motor configuration: models (protocol ranges), instances (id, joint, sign, offset, gear) and
joint <-> motor conversions.

Sides and units
---------------
*Motor side* is what the actuator firmware sees and reports: the output shaft of the actuator
package (for geared actuators such as the AK80-9 or DM8009 the internal reducer is already inside
the firmware's numbers). All protocol ranges of a :class:`MotorModel` (the firmware's P_MAX,
V_MAX, KP/KD range, T_MAX) are motor side, because that is where the firmware clamps.

*Joint side* is the robot description's joint coordinate. Between the two there may be an external
transmission (belt, linkage) of ratio ``gear_ratio`` (motor radians per joint radian), a mounting
direction ``sign`` (+1 or -1) and a calibration offset ``zero_offset``::

    q       = sign * p_motor / gear_ratio + zero_offset     p_motor   = sign * gear_ratio * (q - zero_offset)
    dq      = sign * v_motor / gear_ratio                   v_motor   = sign * gear_ratio * dq
    tau     = sign * gear_ratio * tau_motor                 tau_motor = sign * tau / gear_ratio
    kp, kd  = gear_ratio**2 * (kp_motor, kd_motor)          (stiffness and damping reflect with the square)

``zero_offset`` is on the joint side: the joint angle (rad) at which the motor reads 0, i.e. the
calibration pose at which "set zero" was sent. It is the brief's ``q = sign * (p - offset) / gear``
with a motor-side offset of ``-sign * gear_ratio * zero_offset``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

RANGE_FIELDS: tuple[str, ...] = ("position", "velocity", "kp", "kd", "torque")
"""The five ranged fields of an MIT-style command, in wire order."""

_GAIN_FIELDS = frozenset({"kp", "kd"})


@dataclass(frozen=True, slots=True)
class Range:
    """A closed interval ``[min, max]`` that a protocol field's integer codes span."""

    min: float
    max: float

    def __post_init__(self) -> None:
        for v in (self.min, self.max):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"range bounds must be finite numbers, got [{self.min!r}, {self.max!r}]")
        if not self.min < self.max:
            raise ValueError(f"range min {self.min} must be < max {self.max}")

    @classmethod
    def symmetric(cls, limit: float) -> Range:
        """``[-limit, limit]``."""
        return cls(-float(limit), float(limit))

    @classmethod
    def parse(cls, value: Any, *, gain: bool = False) -> Range:
        """A range from configuration: ``[min, max]``, ``{min = .., max = ..}`` or one number ``x``,
        meaning ``[-x, x]`` (``[0, x]`` for a gain, whose range starts at 0)."""
        if isinstance(value, Range):
            return value
        if isinstance(value, Mapping):
            extra = set(value) - {"min", "max"}
            if extra or not {"min", "max"} <= set(value):
                raise ValueError(f"a range table needs exactly the keys min and max, got {sorted(value)}")
            return cls(value["min"], value["max"])
        if isinstance(value, (list, tuple)):
            if len(value) != 2:
                raise ValueError(f"a range list needs 2 numbers [min, max], got {len(value)}")
            return cls(value[0], value[1])
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if not value > 0:
                raise ValueError(f"a single-number range must be > 0, got {value}")
            return cls(0.0, float(value)) if gain else cls.symmetric(value)
        raise ValueError(f"cannot read a range from {value!r}")

    @property
    def span(self) -> float:
        return self.max - self.min

    @property
    def magnitude(self) -> float:
        """The largest magnitude representable in both directions, ``min(-min, max)`` (0 if none)."""
        return max(0.0, min(-self.min, self.max))


@dataclass(frozen=True)
class MotorModel:
    """One actuator model's MIT-mode ranges (motor side, see module doc) and default reply variant.

    ``position`` rad, ``velocity`` rad/s, ``kp`` N m/rad, ``kd`` N m s/rad, ``torque`` N m. These must
    equal what the firmware is configured with, or commands and replies are scaled wrongly.
    """

    name: str
    position: Range
    velocity: Range
    kp: Range
    kd: Range
    torque: Range
    reply: str = "original"
    note: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("a motor model needs a name")
        for name in RANGE_FIELDS:
            if not isinstance(getattr(self, name), Range):
                raise ValueError(f"motor model {self.name!r}: {name} must be a Range")
        for name in _GAIN_FIELDS:
            if getattr(self, name).min < 0:
                raise ValueError(f"motor model {self.name!r}: {name} range must not go below 0")

    @property
    def ranges(self) -> tuple[Range, Range, Range, Range, Range]:
        """The five command ranges in wire order (position, velocity, kp, kd, torque)."""
        return (self.position, self.velocity, self.kp, self.kd, self.torque)

    def with_overrides(self, **overrides: Any) -> MotorModel:
        """A copy with some fields replaced; range fields accept anything :meth:`Range.parse` reads."""
        known = {f.name for f in fields(self)}
        unknown = set(overrides) - known
        if unknown:
            raise ValueError(f"unknown motor model field(s) {sorted(unknown)}; known: {sorted(known)}")
        parsed = {
            k: Range.parse(v, gain=k in _GAIN_FIELDS) if k in RANGE_FIELDS else v for k, v in overrides.items()
        }
        return replace(self, **parsed)


def _mit(name: str, p: float, v: float, t: float, reply: str, note: str) -> MotorModel:
    """A preset with symmetric P/V/T ranges and the usual KP 0..500, KD 0..5."""
    gains = (Range(0.0, 500.0), Range(0.0, 5.0))
    return MotorModel(name, Range.symmetric(p), Range.symmetric(v), *gains, Range.symmetric(t), reply, note)


_CUBEMARS = "CubeMars AK series driver manual (MIT mode table)"
_DAMIAO = "Damiao factory default PMAX/VMAX/TMAX"

MOTOR_PRESETS: Mapping[str, MotorModel] = MappingProxyType(
    {
        m.name: m
        for m in (
            _mit("MINI-CHEETAH", 12.5, 65.0, 18.0, "original", "Ben Katz mini-cheetah motor-control firmware defaults"),
            _mit("AK60-6", 12.5, 45.0, 15.0, "cubemars", _CUBEMARS),
            _mit("AK70-10", 12.5, 50.0, 25.0, "cubemars", _CUBEMARS),
            _mit("AK80-9", 12.5, 50.0, 18.0, "cubemars", _CUBEMARS),
            _mit("AK10-9", 12.5, 50.0, 65.0, "cubemars", _CUBEMARS),
            _mit("DM4310", 12.5, 30.0, 10.0, "damiao", _DAMIAO),
            _mit("DM4340", 12.5, 8.0, 28.0, "damiao", _DAMIAO),
            _mit("DM6006", 12.5, 45.0, 20.0, "damiao", _DAMIAO),
            _mit("DM8006", 12.5, 45.0, 40.0, "damiao", _DAMIAO),
            _mit("DM8009", 12.5, 45.0, 54.0, "damiao", _DAMIAO),
            _mit("DM10010", 12.5, 20.0, 200.0, "damiao", _DAMIAO),
            _mit(
                "GIM8108",
                12.5,
                45.0,
                40.0,
                "original",
                "Steadywin GIM8108-8 with MIT firmware; ranges are firmware settings: verify V/T against the drive",
            ),
        )
    }
)
"""Well-known MIT-mode models, motor side. The firmware's configured ranges are what count: override
any field in ``hardware.toml`` when a drive was configured differently."""


def motor_preset(name: str) -> MotorModel:
    """The preset called ``name``; ``ValueError`` naming the known presets if there is none."""
    try:
        return MOTOR_PRESETS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown motor model preset {name!r}; known: {', '.join(sorted(MOTOR_PRESETS))}") from None


@dataclass(frozen=True)
class MotorConfig:
    """One motor on a bus: CAN id, model, the joint it drives and the joint <-> motor mapping."""

    can_id: int
    model: MotorModel
    joint: str
    sign: int = 1
    zero_offset: float = 0.0  # rad, joint side: the joint angle at which the motor reads 0
    gear_ratio: float = 1.0  # motor rad per joint rad (external transmission), > 0
    reply: str | None = None  # reply variant; None = the model's default

    def __post_init__(self) -> None:
        if isinstance(self.can_id, bool) or not isinstance(self.can_id, int) or not 0 <= self.can_id <= 0x1FFFFFFF:
            raise ValueError(f"motor {self.joint!r}: CAN id must be an integer in 0..0x1FFFFFFF, got {self.can_id!r}")
        if not isinstance(self.model, MotorModel):
            raise ValueError(f"motor {self.joint!r}: model must be a MotorModel")
        if not isinstance(self.joint, str) or not self.joint:
            raise ValueError(f"motor id {self.can_id}: joint must be a non-empty string")
        if isinstance(self.sign, bool) or not isinstance(self.sign, int) or self.sign not in (1, -1):
            raise ValueError(f"motor {self.joint!r}: sign must be +1 or -1, got {self.sign!r}")
        for name in ("zero_offset", "gear_ratio"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"motor {self.joint!r}: {name} must be a finite number, got {v!r}")
        if not self.gear_ratio > 0:
            raise ValueError(f"motor {self.joint!r}: gear_ratio must be > 0, got {self.gear_ratio}")
        if self.reply is None:
            object.__setattr__(self, "reply", self.model.reply)

    # Scalar or array conversions (numpy broadcasting applies).
    def position_to_motor(self, q: ArrayLike) -> Any:
        return self.sign * self.gear_ratio * (np.asarray(q, dtype=float) - self.zero_offset)

    def position_to_joint(self, p: ArrayLike) -> Any:
        return self.sign * np.asarray(p, dtype=float) / self.gear_ratio + self.zero_offset

    def velocity_to_motor(self, dq: ArrayLike) -> Any:
        return self.sign * self.gear_ratio * np.asarray(dq, dtype=float)

    def velocity_to_joint(self, v: ArrayLike) -> Any:
        return self.sign * np.asarray(v, dtype=float) / self.gear_ratio

    def torque_to_motor(self, tau: ArrayLike) -> Any:
        return self.sign * np.asarray(tau, dtype=float) / self.gear_ratio

    def torque_to_joint(self, t: ArrayLike) -> Any:
        return self.sign * self.gear_ratio * np.asarray(t, dtype=float)

    def gains_to_motor(self, kp: ArrayLike, kd: ArrayLike) -> tuple[Any, Any]:
        """Joint-side stiffness/damping to motor side (divide by gear_ratio**2; sign cancels)."""
        g2 = self.gear_ratio**2
        return np.asarray(kp, dtype=float) / g2, np.asarray(kd, dtype=float) / g2

    @property
    def joint_effort_limit(self) -> float:
        """The largest joint torque (N m) the command range can express in both directions."""
        return self.model.torque.magnitude * self.gear_ratio


class MotorGroup:
    """An ordered set of motors with per-motor arrays for vectorized joint <-> motor conversion.

    Arrays in and out are in the group's motor order; scalars broadcast.
    """

    def __init__(self, motors: Sequence[MotorConfig]) -> None:
        self.motors: tuple[MotorConfig, ...] = tuple(motors)
        self.sign: NDArray[np.float64] = np.array([m.sign for m in self.motors], dtype=float)
        self.gear: NDArray[np.float64] = np.array([m.gear_ratio for m in self.motors], dtype=float)
        self.offset: NDArray[np.float64] = np.array([m.zero_offset for m in self.motors], dtype=float)
        self._sg = self.sign * self.gear
        self._s_over_g = self.sign / self.gear
        self._g2 = self.gear**2
        # The same conversions as blocks (commands: rows q, dq, kp, kd, tau; states: columns
        # position, velocity, torque), for the control loop's one-operation-per-step form.
        n = len(self.motors)
        self._command_scale = np.vstack([self._sg, self._sg, 1 / self._g2, 1 / self._g2, self._s_over_g])
        self._command_offset = np.zeros((5, n))
        self._command_offset[0] = -self._sg * self.offset
        self._state_scale = np.column_stack([self._s_over_g, self._s_over_g, self._sg])
        self._state_offset = np.column_stack([self.offset, np.zeros(n), np.zeros(n)])
        for a in (self.sign, self.gear, self.offset, self._sg, self._s_over_g, self._g2, self._command_scale, self._command_offset,
                  self._state_scale, self._state_offset):  # fmt: skip
            a.flags.writeable = False

    def __len__(self) -> int:
        return len(self.motors)

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(m.joint for m in self.motors)

    def command_to_motor(
        self, q: ArrayLike, dq: ArrayLike, kp: ArrayLike, kd: ArrayLike, tau: ArrayLike
    ) -> tuple[NDArray[np.float64], ...]:
        """Joint-side (q, dq, kp, kd, tau) to motor-side (position, velocity, kp, kd, torque)."""
        return (
            self._sg * (np.asarray(q, dtype=float) - self.offset),
            self._sg * np.asarray(dq, dtype=float),
            np.asarray(kp, dtype=float) / self._g2,
            np.asarray(kd, dtype=float) / self._g2,
            self._s_over_g * np.asarray(tau, dtype=float),
        )

    def commands_to_motor(self, rows: NDArray[np.float64]) -> NDArray[np.float64]:
        """:meth:`command_to_motor` on a ``(5, N)`` block of joint-side rows (q, dq, kp, kd, tau),
        in place: the control loop's form, one operation per step instead of one per field."""
        rows *= self._command_scale
        rows += self._command_offset
        return rows

    def states_to_joint(self, states: NDArray[np.float64], motors: Any = slice(None)) -> NDArray[np.float64]:
        """:meth:`state_to_joint` on ``(M, 3)`` rows of motor-side (position, velocity, torque)
        of the motors ``motors`` (indices, default all in order), as new ``(M, 3)`` rows."""
        joint = states * self._state_scale[motors]
        joint += self._state_offset[motors]
        return joint

    def state_to_joint(
        self, position: ArrayLike, velocity: ArrayLike, torque: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Motor-side (position, velocity, torque) to joint-side (q, dq, tau)."""
        return (
            self._s_over_g * np.asarray(position, dtype=float) + self.offset,
            self._s_over_g * np.asarray(velocity, dtype=float),
            self._sg * np.asarray(torque, dtype=float),
        )
