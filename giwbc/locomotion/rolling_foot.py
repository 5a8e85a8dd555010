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


__all__ = ["cop_on_raised_side", "lateral_rise"]
