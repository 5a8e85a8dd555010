"""The estimator's ``omega_lead`` (issue 41): a base rate read late, led along its derivative,
is closer to the rate now than the late reading (a stiff, lagged plant is sensitive to the delay)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.estimation.estimator import EstimatorConfig, StateEstimator


@pytest.mark.parametrize("lead", [0.004])
def test_led_rate_is_closer_to_the_rate_now(g1, lead: float) -> None:
    """A 6 Hz, 0.3 rad/s base roll rate sampled 2 ticks (4 ms) late: led by 4 ms it is nearer the
    true rate now (RMS) than the late sample, which is 0.045 rad/s off."""
    dt, late, frequency = 0.002, 2, 6.0
    estimator = StateEstimator(g1, EstimatorConfig(omega_lead=lead))
    times = np.arange(0.0, 1.0, dt)
    rate = 0.3 * np.sin(2.0 * math.pi * frequency * times)
    lagged = np.concatenate([np.zeros(late), rate[:-late]])
    led = np.array([estimator._led_omega((float(w), 0.0, 0.0), dt)[0] for w in lagged])
    settled = times > 0.2
    error_late = np.sqrt(np.mean((lagged - rate)[settled] ** 2))
    error_led = np.sqrt(np.mean((led - rate)[settled] ** 2))
    assert error_late > 0.03
    assert error_led < 0.6 * error_late


def test_omega_lead_rejects_a_negative_lead() -> None:
    with pytest.raises(ValueError, match="omega_lead"):
        EstimatorConfig(omega_lead=-0.01)
