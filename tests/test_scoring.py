"""Scoring on episodes that must fail: a push no controller survives, and an episode that survives
but does not end upright. Short episodes (well under a second of simulated time) keep them cheap."""

from __future__ import annotations

import math

import pytest

from giwbc.evaluation import PushProtocol, run_episodes
from giwbc.sim_to_sim import PushSetting, evaluate

# 2000 N for 0.2 s is 400 N s on a 33 kg robot (12 m/s): no controller stays up.
HOPELESS = PushProtocol(force=2000.0, duration=0.2, interval=(0.2, 0.2), episode_seconds=0.6)
# 30 N for 0.1 s: the WBC stands through it (test_evaluation.py), but never ends *exactly* level.
GENTLE = PushProtocol(force=30.0, duration=0.1, interval=(0.2, 0.2), episode_seconds=0.5)


@pytest.fixture(scope="module")
def g1_model(g1):
    return g1.build_mujoco()


def test_a_push_no_controller_survives_is_scored_as_a_fall() -> None:
    arm = run_episodes(None, protocol=HOPELESS, episodes=1, seed=5, workers=1)
    (episode,) = arm.episodes
    assert not episode.survived and not episode.success
    assert episode.survival_time < HOPELESS.episode_seconds - 0.05  # terminated early, not at the time limit
    assert episode.max_tilt > 0.5 or episode.final_tilt > 0.5
    assert math.isfinite(episode.push_time)
    assert arm.success_rate == 0.0 and arm.survival_rate == 0.0


def test_an_episode_that_survives_tilted_is_not_a_success() -> None:
    """Survival and success are scored apart: with an upright limit tighter than the robot's final
    tilt, an episode that ran to the time limit still fails."""
    standing = run_episodes(None, protocol=GENTLE, episodes=1, seed=5, workers=1)
    (episode,) = standing.episodes
    assert episode.survived and episode.success
    assert episode.survival_time == pytest.approx(GENTLE.episode_seconds)
    strict = PushProtocol(**{**GENTLE.__dict__, "upright_tilt": episode.final_tilt / 2})
    (tilted,) = run_episodes(None, protocol=strict, episodes=1, seed=5, workers=1).episodes
    assert tilted.survived and not tilted.success
    assert tilted.final_tilt == episode.final_tilt  # the same episode, only scored differently


def test_sim_to_sim_scores_a_fall_as_a_failure(g1_model) -> None:
    cells = evaluate(episodes=1, seconds=0.6, pushes=PushSetting(force=2000.0, duration=0.2, interval=(0.2, 0.2)),
                     workers=0, seed=4, conditions=("mujoco_nominal",), env_kwargs={"model": g1_model})
    cell = cells["wbc_only"]["mujoco_nominal"]
    assert cell.episodes == 1 and cell.successes == 0 and cell.success_rate == 0.0
    assert cell.failed_seeds == [4]
    assert cell.simulated_s < 0.55  # it stopped at the fall, not at the end


def test_sim_to_sim_scores_a_standing_episode_as_a_success(g1_model) -> None:
    cells = evaluate(episodes=1, seconds=0.3, pushes=PushSetting(force=30.0, duration=0.1, interval=(0.1, 0.2)),
                     workers=0, seed=4, conditions=("mujoco_nominal",), env_kwargs={"model": g1_model})
    cell = cells["wbc_only"]["mujoco_nominal"]
    assert (cell.episodes, cell.successes, cell.failed_seeds) == (1, 1, [])
    assert cell.simulated_s == pytest.approx(0.3)
