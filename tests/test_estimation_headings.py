"""Held foot headings: a slow drift (a gyro bias) is an error to correct, a fast turn is a slip to re-anchor."""

from __future__ import annotations

import math

import pytest

from giwbc.estimation.headings import FootHeadings

DT = 0.002


def test_a_slow_drift_keeps_the_anchor_and_grows_the_error() -> None:
    headings = FootHeadings(2, math.radians(0.4), 0.05)
    rate = math.radians(2.0)  # 2 deg/s: a cheap IMU's uncalibrated yaw bias
    for k in range(int(3.0 / DT)):
        error = headings.update(0, k * DT, 0.3 + rate * k * DT)
    assert headings.twists == 0 and headings.held[0] == 0.3
    assert error == pytest.approx(-rate * (int(3.0 / DT) - 1) * DT)  # 6 degrees: far beyond the twist threshold


def test_a_fast_twist_re_anchors_and_a_lift_forgets() -> None:
    headings = FootHeadings(2, math.radians(0.4), 0.05)
    for k in range(100):
        headings.update(1, k * DT, 0.0)
    twist = math.radians(0.6)
    for k in range(100, 120):  # 0.6 deg within 40 ms, split over two windows
        error = headings.update(1, k * DT, twist * (k - 99) / 20)
    assert headings.twists == 1 and abs(error) < math.radians(0.4)
    assert headings.held[1] is not None and headings.held[1] > 0.0  # re-anchored on the turned foot
    assert headings.held[0] is None  # the other foot never came down
    headings.lift(1)
    assert headings.held[1] is None and headings.update(1, 1.0, 0.2) == 0.0 and headings.held[1] == 0.2


def test_foot_headings_reject_bad_thresholds() -> None:
    with pytest.raises(ValueError, match="must be > 0"):
        FootHeadings(2, 0.0, 0.05)
