"""The CoP band about the stance sole's centre line (``WalkerConfig.cop_lateral_band``, issue 41): in
single support the CoP the walker asks stays within the band across the stance foot, its along-foot
part kept; a point or rim sole is not asked for a CoP at its edge, where it would roll."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion.rolling_foot import cop_within_band
from giwbc.locomotion.simulation import simulate_walk
from giwbc.locomotion.walker import Phase, WalkingController
from giwbc.locomotion.walker_config import WalkerConfig
from giwbc.robot.description import load


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5])
def test_cop_is_clipped_across_the_foot_along_the_foot_kept(yaw: float) -> None:
    position = np.array([0.3, -0.1])
    along, across = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
    for lateral in (0.025, -0.025):
        asked = position + 0.03 * along + lateral * across
        cop, moved = cop_within_band(asked, position, yaw, 0.015)
        assert moved
        assert float((cop - position) @ across) == pytest.approx(math.copysign(0.015, lateral))
        assert float((cop - position) @ along) == pytest.approx(0.03)
    inside = position - 0.05 * along + 0.01 * across
    cop, moved = cop_within_band(inside, position, yaw, 0.015)
    assert not moved and np.array_equal(cop, inside)


@pytest.mark.parametrize("value", [-0.01, float("nan"), float("inf")])
def test_a_bad_band_is_refused(value: float) -> None:
    with pytest.raises(ValueError, match="cop_lateral_band"):
        WalkerConfig(cop_lateral_band=value)


def _largest_lateral_cop(config: WalkerConfig) -> tuple[float, int]:
    """The largest |CoP offset across the stance sole| the walker asked in single support over a short
    walk at 0.3 m/s (nominal plant, seed 20000), and how many single-support ticks were seen."""
    seen: list[float] = []

    def observe(_robot: object, controller: WalkingController) -> None:
        state = controller.state
        if state.phase is Phase.SINGLE:
            foot = controller.feet[state.stance]
            c, s = math.cos(foot.yaw), math.sin(foot.yaw)
            d = state.cop - foot.position[:2]
            seen.append(abs(-s * float(d[0]) + c * float(d[1])))

    run = simulate_walk(load("g1"), (0.3, 0.0, 0.0), 2.5, config=config, seed=20000, observe=observe)
    assert not run.fell
    return max(seen), len(seen)


def test_walker_cop_reference_is_held_within_the_band() -> None:
    """Without the band the DCM controller asks CoPs beyond 6 mm of the centre line during a
    walk's start; with a 6 mm band every single-support tick's CoP is within it."""
    free, ticks = _largest_lateral_cop(WalkerConfig())
    assert ticks > 100 and free > 0.006
    held, ticks = _largest_lateral_cop(WalkerConfig(cop_lateral_band=0.006))
    assert ticks > 100 and held <= 0.006 + 1e-9
