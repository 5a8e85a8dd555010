"""WalkerConfig.contact_kd (issue 41): the damping the WBC puts on each loaded foot's twist, over
BalanceConfig.contact_kd — on an estimated state that twist carries the estimate's (late or led) base
rate times the leg, fed back at this gain through a hard constraint."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion.walker import WalkingController
from giwbc.locomotion.walker_config import WalkerConfig
from giwbc.robot import load


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def _foot_twist_rates(g1, config: WalkerConfig) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per foot contact: (its twist J v, its planned twist rate J q̈ + J̇ v) at one tick of a standing
    G1 whose pelvis turns at 0.5 rad/s in roll (the feet moving with it: what a late rate looks like)."""
    walker = WalkingController(g1, config)
    q = g1.default_configuration()
    walker.reset(q)
    v = np.zeros(walker.model.nv)
    v[3] = 0.5  # base roll rate, rad/s (Pinocchio: base frame)
    result = walker.update(q, v, 0.0)
    assert result.ok, result.message
    kin = walker.wbc.kin
    rates = []
    for contact in walker.balance.contacts:
        contact.update(kin)
        twist = contact.jacobian @ v
        rates.append((twist, contact.jacobian @ result.qdd + contact.drift))
    return rates


def test_contact_kd_sets_the_feet_twist_damping(g1) -> None:
    assert [c.kd for c in WalkingController(g1, WalkerConfig()).balance.contacts] == [20.0, 20.0]
    assert [c.kd for c in WalkingController(g1, WalkerConfig(contact_kd=5.0)).balance.contacts] == [5.0, 5.0]
    for kd in (5.0, 20.0):
        for twist, rate in _foot_twist_rates(g1, WalkerConfig(contact_kd=kd)):
            assert np.linalg.norm(twist) > 0.1  # the turning pelvis moves the feet (0.5 rad/s x ~0.7 m)
            np.testing.assert_allclose(rate, -kd * twist, atol=1e-6)  # the contact rows are hard: the twist decays at kd


@pytest.mark.parametrize("kd", [-1.0, math.nan, math.inf])
def test_contact_kd_refuses_a_bad_damping(kd: float) -> None:
    with pytest.raises(ValueError, match="contact_kd"):
        WalkerConfig(contact_kd=kd)
