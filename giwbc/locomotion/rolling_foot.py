"""A stance foot that rolls about its long axis, watched from its measured rotation, and the CoP the
walker may still ask of it.

A sole that touches through a few points or a rounded rim (a heel point and two toe points, capsules,
a worn rubber edge) gives no CoP beyond the line it stands on: asked for one there (the DCM controller
clips its CoP to the controller's rectangle, not to the real sole), the foot rolls onto that line and
its ankle roll follows the roll to its limit. A loaded foot turning about its long axis is that CoP
refused: its sole's lateral tilt (the height gradient across it, from the walker's own kinematics on
the measured or estimated state) past ``tilt`` says which side went down. Then the CoP asked is held
on the raised side of the sole's centre line (``margin`` m inside it): the ankle's torque, pushing on
the side that still touches, brings the foot back flat instead of rolling it further, and the DCM
error it leaves is the step adapter's.

A stance foot can also turn about the vertical on a floor that does not hold the yaw moment the WBC
plans on it (a compliant floor creeps far inside its friction: MuJoCo's soft contact, a gym mat).
:class:`YawSlipWatch` keeps, per single support, how far the stance sole's heading has turned since
the support began: past ``angle`` the floor is taken as not holding yaw for ``hold`` s (the walker
then asks the limbs' yaw momentum task for more: giwbc.control.yaw_momentum). On the G1 (truth,
any_floor, 8 s at 0.3 / 0.5 m/s and turning 0.3 rad/s, seed 20001) a single support's largest turn
is 1-2 deg on the box-footed plants, 2-5 deg on point feet, 7-12 deg on capsule and rounded feet
(a rim-rolling sole's heading) and 8-16 deg on the soft floor.
"""

from __future__ import annotations

import math

import numpy as np


def lateral_rise(rotation: np.ndarray) -> float:
    """The sole's height gradient across it (m per m, the world z of its +y axis): > 0 when the
    foot has rolled onto its -y edge (the +y edge raised), < 0 onto its +y edge, 0 flat."""
    return float(rotation[2, 1])


def cop_on_raised_side(cop: np.ndarray, position: np.ndarray, yaw: float, rise: float, tilt: float, margin: float = 0.0) -> tuple[np.ndarray, bool]:
    """``(cop, moved)``: the CoP ``cop`` (world xy) asked of a stance foot at ``position`` heading
    ``yaw`` whose sole rises ``rise`` across it (:func:`lateral_rise`); with the foot rolled past
    ``tilt`` rad the CoP's lateral coordinate in the foot frame is held at least ``margin`` m on
    the raised side of the centre line (moved only across the foot, its along-foot part kept)."""
    if abs(rise) <= math.sin(tilt):
        return cop, False
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = float(cop[0] - position[0]), float(cop[1] - position[1])
    lateral = -s * dx + c * dy
    up = 1.0 if rise > 0.0 else -1.0
    wanted = up * margin
    if up * lateral >= margin:
        return cop, False
    shift = wanted - lateral
    return np.array([cop[0] - s * shift, cop[1] + c * shift]), True


def heading(rotation: np.ndarray) -> float:
    """A sole's heading (rad): the world yaw of its +x axis."""
    return math.atan2(float(rotation[1, 0]), float(rotation[0, 0]))


class YawSlipWatch:
    """Whether a stance foot has lately turned more than ``angle`` rad within one single support
    (see the module docstring); ``hold`` s after the last such turn it reads False again."""

    def __init__(self, angle: float, hold: float) -> None:
        if not (math.isfinite(angle) and angle > 0.0):
            raise ValueError(f"yaw slip angle must be a finite angle > 0, got {angle!r}")
        if not (hold >= 0.0):
            raise ValueError(f"yaw slip hold must be >= 0 s, got {hold!r}")
        self.angle, self.hold = float(angle), float(hold)
        self.reset()

    def reset(self) -> None:
        self._support: object = None
        self._start = 0.0
        self.turned = 0.0  # rad: the current single support's largest turn so far
        self.last_slip: float | None = None  # s: when a turn last passed ``angle``
        self.slips = 0  # single supports in which the stance foot turned past ``angle``

    def update(self, t: float, support: object, yaw: float | None) -> bool:
        """One tick at ``t``: ``support`` names the single support (a new value starts one: the
        stance side and its start time), ``yaw`` the stance sole's heading (None: not in single
        support). Returns whether the floor is taken as not holding yaw now."""
        if yaw is None:
            self._support = None
        else:
            if support != self._support:
                self._support, self._start, self.turned = support, yaw, 0.0
            turned = abs(math.remainder(yaw - self._start, math.tau))
            if turned > self.angle:
                if self.turned <= self.angle:
                    self.slips += 1
                self.last_slip = t
            self.turned = max(self.turned, turned)
        return self.last_slip is not None and t - self.last_slip <= self.hold


__all__ = ["YawSlipWatch", "cop_on_raised_side", "heading", "lateral_rise"]
