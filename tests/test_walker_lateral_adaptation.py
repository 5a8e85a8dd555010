"""The step adapter's lateral channel (``WalkerConfig.adapt_lateral_deadband``, issue 41): the DCM
error across the stance foot's heading reaches the adapter through its own, smaller deadband, so a
lateral error that a point or rim foot's ankle cannot take back is stepped away; the forward error
keeps the common deadband."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion.step_adapter import DcmErrorShaper
from giwbc.locomotion.swing_control import SwingControl
from giwbc.locomotion.walker_config import WalkerConfig


class _Reference:
    """A nominal DCM held at one point (the part of a DcmReference the adaptation reads)."""

    def __init__(self, point: np.ndarray) -> None:
        self.point = point

    def evaluate(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.point.copy(), np.zeros(2), self.point.copy()


def _channel(lateral_deadband: float, filter_time: float = 0.0) -> SwingControl:
    control = SwingControl.__new__(SwingControl)
    control._step_reference = _Reference(np.array([1.0, 2.0]))
    control._lateral_shaper = DcmErrorShaper(lateral_deadband, filter_time)
    return control


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5])
def test_lateral_error_passes_its_own_deadband_forward_error_is_kept(yaw: float) -> None:
    """A 2.5 cm lateral and 1.5 cm forward error (inside a 3 cm common deadband, so the common shaper
    gives the nominal DCM): with a 1 cm lateral deadband the adapter sees 1.5 cm of the lateral error
    on the stance heading's left and the common shaper's forward part (nothing) along it."""
    control = _channel(0.01)
    nominal = control._step_reference.point
    forward, left = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
    xi = nominal + 0.015 * forward + 0.025 * left
    common = DcmErrorShaper(0.03)(0.0, xi, nominal)
    np.testing.assert_allclose(common, nominal, atol=1e-12)  # inside the common deadband
    seen = control._lateral_error_through(0.0, xi, common, yaw)
    assert float((seen - nominal) @ left) == pytest.approx(0.015, abs=1e-12)
    assert float((seen - nominal) @ forward) == pytest.approx(0.0, abs=1e-12)


def test_forward_part_of_the_common_shaper_is_untouched() -> None:
    """A forward error beyond the common deadband reaches the adapter as the common shaper gives it;
    a lateral error inside the lateral deadband is taken out."""
    control = _channel(0.01)
    nominal = control._step_reference.point
    xi = nominal + np.array([0.08, 0.005])  # yaw 0: x forward, y left
    common = DcmErrorShaper(0.03)(0.0, xi, nominal)
    seen = control._lateral_error_through(0.0, xi, common, 0.0)
    assert seen[0] == pytest.approx(common[0], abs=1e-12)
    assert seen[1] == pytest.approx(nominal[1], abs=1e-12)


def test_lateral_error_is_low_passed() -> None:
    """With adapt_filter's time constant, a lateral error that appears at once reaches the adapter
    gradually: after one time constant about 63 % of it (no deadband)."""
    control = _channel(0.0, filter_time=0.02)
    nominal = control._step_reference.point
    control._lateral_error_through(0.0, nominal.copy(), nominal.copy(), 0.0)
    seen = nominal.copy()
    for k in range(1, 11):  # 10 ticks of 2 ms: one time constant
        xi = nominal + np.array([0.0, 0.04])
        seen = control._lateral_error_through(0.002 * k, xi, nominal.copy(), 0.0)
    assert 0.55 * 0.04 < seen[1] - nominal[1] < 0.7 * 0.04


@pytest.mark.parametrize("value", [-0.01, float("nan"), float("inf")])
def test_a_bad_lateral_deadband_is_refused(value: float) -> None:
    with pytest.raises(ValueError, match="adapt_lateral_deadband"):
        WalkerConfig(adapt_lateral_deadband=value)


def test_the_channel_acts_on_an_estimated_dcm_only(g1) -> None:
    """any_floor alone (the walker on the MuJoCo truth) shapes nothing: the adapter takes the measured
    DCM whole and the lateral channel stays out; over the deployment preset (an estimated DCM, 3 cm
    deadband) the lateral error gets its own, zero deadband."""
    from giwbc.locomotion.walker import WalkingController
    from giwbc.locomotion.walker_config import ANY_FLOOR_OPTIONS, DEPLOYMENT_OPTIONS, walker_config

    truth = WalkingController(g1, walker_config("any_floor"))
    truth.reset()
    assert truth.config.adapt_lateral_deadband == 0.0 and not truth._dcm_shaper.active
    estimate = WalkingController(g1, walker_config({**DEPLOYMENT_OPTIONS, **ANY_FLOOR_OPTIONS}))  # (robustness.py --estimator)
    estimate.reset()
    assert estimate._dcm_shaper.active and estimate._lateral_shaper.deadband == 0.0
