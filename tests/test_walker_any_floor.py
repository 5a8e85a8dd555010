"""The "any_floor" walker preset (issue 36): a WBC that plans every foot force inside a 0.5 friction
pyramid, for floors and feet the walker was not tuned on (giwbc.locomotion.walker_config.ANY_FLOOR_OPTIONS)."""

from __future__ import annotations

import math

import pytest

from giwbc.locomotion.simulation import Push, simulate_walk
from giwbc.locomotion.walker import WalkingController
from giwbc.locomotion.walker_config import ANY_FLOOR_OPTIONS, WalkerConfig, walker_config
from giwbc.robot import load


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def _planned_friction_ratio(description, config: WalkerConfig, **walk) -> tuple[float, object]:
    """The largest |f_t| / f_n of a planned foot force (its contact frame: tangential over normal; feet
    loaded over 20 N) over a run."""
    worst = [0.0]

    def observe(robot, controller) -> None:
        result = controller.last_result
        if result is None:
            return
        for name in result.contact_wrenches:
            force = result.contact_wrenches[name][:3]
            if force[2] > 20.0:
                worst[0] = max(worst[0], math.hypot(force[0], force[1]) / force[2])

    run = simulate_walk(description, observe=observe, config=config, **walk)
    return worst[0], run


def test_the_preset_sets_the_friction_the_wbc_plans_with(g1) -> None:
    walker = WalkingController(g1, walker_config("any_floor"))
    assert [c.mu for c in walker.balance.contacts] == [ANY_FLOOR_OPTIONS["friction"]] * 2
    assert [c.mu for c in WalkingController(g1).balance.contacts] == [WalkerConfig().balance.mu] * 2
    with pytest.raises(ValueError, match="friction"):
        WalkerConfig(friction=0.0)


def test_a_push_on_a_soft_slippery_floor_is_caught_inside_the_floors_friction(g1) -> None:
    """The soft floor's sliding friction is 0.6: the preset's plan stays inside 0.5 per axis (0.71 on a
    diagonal) through a 100 N x 0.2 s push at 45 deg and the G1 recovers; the default walker's plan
    asks for more tangential force than that floor gives (its 0.8 pyramid)."""
    push = Push(2.0, 100.0, math.pi / 4, 0.2)
    walk = dict(command=(0.0, 0.0, 0.0), seconds=2.0 + 0.2 + 3.0, pushes=(push,), command_start=None, seed=20001, plant="soft_floor")
    ratio, run = _planned_friction_ratio(g1, walker_config("any_floor"), **walk)
    assert not run.fell, f"fell at {run.fall_time:.2f} s"
    assert ratio <= 0.5 * math.sqrt(2.0) * 1.001  # (the QP's tolerance)
    default_ratio, _ = _planned_friction_ratio(g1, WalkerConfig(), **walk)
    assert default_ratio > 0.6, default_ratio


def test_the_walking_limit_spring_is_on_only_while_walking(g1) -> None:
    """``walking_limit_spring``: the WBC's joint-limit spring while the walker walks, BalanceConfig's
    (none) while it stands."""
    spring = (0.05, 600.0, 10.0)
    seen: dict[bool, set] = {False: set(), True: set()}

    def observe(robot, controller) -> None:
        seen[controller.walking].add(controller.wbc.limit_spring)

    simulate_walk(g1, (0.3, 0.0, 0.0), 1.0, command_start=0.5, config=WalkerConfig(walking_limit_spring=spring), observe=observe)
    assert seen == {False: {None}, True: {spring}}
    with pytest.raises(ValueError, match="walking_limit_spring"):
        WalkerConfig(walking_limit_spring=(0.0, 600.0, 10.0))
