"""Scoring on episodes that must fail: a push no controller survives, an episode that survives
but does not end upright, and a fall two seconds after the push. Every episode runs on
SETTLE_AFTER_PUSH_S (3 s) after its push; the standing environment simulates that in well under a second."""

from __future__ import annotations

import math

import pytest

from giwbc.apps.evaluation import (
    ArmResult,
    Comparison,
    EpisodeResult,
    PushProtocol,
    format_falls,
    mcnemar_exact,
    run_episodes,
    wilson_interval,
)
from giwbc.apps.sim_to_sim import Cell, PushSetting, evaluate
from giwbc.locomotion.push_scoring import SETTLE_AFTER_PUSH_S

# 2000 N for 0.2 s is 400 N s on a 33 kg robot (12 m/s): no controller stays up.
HOPELESS = PushProtocol(force=2000.0, duration=0.2, interval=(0.2, 0.2), episode_seconds=3.4)
# 30 N for 0.1 s: the WBC stands through it (test_evaluation.py), but never ends *exactly* level.
GENTLE = PushProtocol(force=30.0, duration=0.1, interval=(0.6, 0.6), episode_seconds=3.7)


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
    assert episode.fall_after_push is not None and -0.2 < episode.fall_after_push < 1.0  # s after the push ended
    assert arm.summary()["falls"] == 1 and arm.summary()["fall_after_push_s"] == [round(episode.fall_after_push, 2)]
    assert arm.success_rate == 0.0 and arm.survival_rate == 0.0 and arm.name == "wbc"


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


def test_a_fall_two_seconds_after_the_push_is_a_failure() -> None:
    """The WBC alone at 100 N (seed 30016): still up when the old 2.6 s episodes ended, on the ground 2.1 s after the
    push ended. Scored with the settle window, it is a failure, and its fall is reported with that delay."""
    arm = run_episodes(None, protocol=PushProtocol(force=100.0), episodes=1, seed=30016, workers=1)
    (episode,) = arm.episodes
    assert PushProtocol().episode_seconds == pytest.approx(1.6 + 0.2 + SETTLE_AFTER_PUSH_S)
    assert not episode.survived and not episode.success
    assert episode.survival_time > 2.6  # it would have ended upright in the old window
    assert 1.5 < episode.fall_after_push < SETTLE_AFTER_PUSH_S
    assert episode.survival_time == pytest.approx(episode.push_time + 0.2 + episode.fall_after_push)
    assert format_falls([arm]) == f"falls of wbc at 100 N, s after the push ended: {episode.fall_after_push:.2f}"


def test_sim_to_sim_scores_a_fall_as_a_failure(g1_model) -> None:
    cells = evaluate(episodes=1, seconds=0.6, pushes=PushSetting(force=2000.0, duration=0.2, interval=(0.2, 0.2)),
                     workers=0, seed=4, conditions=("mujoco_nominal",), env_kwargs={"model": g1_model})
    cell = cells["wbc_only"]["mujoco_nominal"]
    assert cell.episodes == 1 and cell.successes == 0 and cell.success_rate == 0.0
    assert cell.failed_seeds == [4]
    assert cell.simulated_s < 0.55  # it stopped at the fall, not at the end
    assert cell.summary()["falls"] == 1 and -0.2 < cell.fall_after_push_s[0] < 0.2  # s after the push ended


def test_sim_to_sim_scores_a_standing_episode_as_a_success(g1_model) -> None:
    """Pushes start within the first 0.8 s; the episode runs on 3 s past the latest possible end of the last one."""
    cells = evaluate(episodes=1, seconds=0.8, pushes=PushSetting(force=30.0, duration=0.1, interval=(0.6, 0.7)),
                     workers=0, seed=4, conditions=("mujoco_nominal",), env_kwargs={"model": g1_model})
    cell = cells["wbc_only"]["mujoco_nominal"]
    assert (cell.episodes, cell.successes, cell.failed_seeds, cell.fall_after_push_s) == (1, 1, [], [])
    assert cell.simulated_s == pytest.approx(0.8 + 0.1 + SETTLE_AFTER_PUSH_S)


# --- the arithmetic of the scores, on made-up episodes -------------------------------------------
def episode(seed: int, survived: bool, success: bool, time: float, tilt: float, force=(80.0, 0.0, 0.0), push_time=1.3,
            ret: float = 10.0) -> EpisodeResult:
    fall = None if survived else time - (push_time + 0.2)
    return EpisodeResult(seed, survived, success, time, tilt, 2 * tilt, push_time, force, ret, fall_after_push=fall)


ARM = ArmResult("wbc", PushProtocol(), (
    episode(1, True, True, 4.8, 0.1, ret=30.0),
    episode(2, True, False, 4.8, 0.5, ret=20.0),
    episode(3, False, False, 1.4, 1.0, ret=-5.0),
    episode(4, False, False, 3.7, 1.2, ret=-5.0),  # fell 2.2 s after the push
))


def test_arm_scores_count_successes_and_survivals_apart() -> None:
    assert (ARM.n, ARM.successes) == (4, 1)
    assert ARM.success_rate == 0.25 and ARM.survival_rate == 0.5
    assert ARM.mean_survival_time == pytest.approx((4.8 + 4.8 + 1.4 + 3.7) / 4)
    low, high = wilson_interval(1, 4)
    assert ARM.summary() == {
        "arm": "wbc", "episodes": 4, "success_rate": 0.25, "success_rate_95ci": [low, high], "survival_rate": 0.5,
        "mean_survival_time_s": pytest.approx(3.675), "mean_return": 10.0, "mean_max_tilt_rad": pytest.approx(1.4),
        "settle_after_push_s": 3.0, "falls": 2, "fall_after_push_s": [-0.1, 2.2], "not_started": 0,
    }  # fmt: skip
    assert format_falls([ARM]) == "falls of wbc at 80 N, s after the push ended: -0.10, 2.20"
    empty = ArmResult("none", PushProtocol(), ())
    assert empty.success_rate == 0.0 and empty.survival_rate == 0.0


def test_wilson_interval_stays_inside_zero_one() -> None:
    for n in (5, 19, 23):  # all successes: the upper end rounds to 1 + 2e-16 before the clamp
        assert wilson_interval(n, n)[1] == 1.0 and wilson_interval(0, n)[0] == 0.0


def test_wilson_interval_matches_published_values() -> None:
    for (successes, n), expected in {(25, 50): (0.3664, 0.6336), (0, 10): (0.0, 0.2775), (10, 10): (0.7225, 1.0),
                                     (3, 20): (0.0524, 0.3604)}.items():  # fmt: skip
        assert wilson_interval(successes, n) == pytest.approx(expected, abs=1e-4)


def test_paired_comparison_counts_saved_and_lost_episodes() -> None:
    residual = ArmResult("policy.onnx", PushProtocol(), (
        episode(1, True, False, 2.6, 0.5),  # lost
        episode(2, True, True, 2.6, 0.1),  # saved
        episode(3, True, True, 2.6, 0.1, push_time=1.5),  # saved; a different push time is fine when the WBC arm fell
        episode(4, False, False, 1.9, 1.1),  # both fail
    ))
    comparison = Comparison(ARM, residual, "giwbc/G1Balance-v0")
    assert (comparison.saved, comparison.lost) == (2, 1)
    assert comparison.same_pushes
    assert comparison.paired_p_value == mcnemar_exact(2, 1) == 1.0
    summary = comparison.summary()
    assert summary["paired"] == {"saved": 2, "lost": 1, "mcnemar_exact_p": 1.0}
    assert summary["env_id"] == "giwbc/G1Balance-v0" and summary["same_pushes"] is True
    assert summary["wbc"] == ARM.summary() and summary["residual"] == residual.summary()
    assert summary["protocol"]["force"] == 80.0
    other_push = ArmResult("p", PushProtocol(), (episode(1, True, True, 2.6, 0.1, force=(0.0, 80.0, 0.0)),) + residual.episodes[1:])
    assert not Comparison(ARM, other_push, "x").same_pushes
    other_time = ArmResult("p", PushProtocol(), (episode(1, True, True, 2.6, 0.1, push_time=1.4),) + residual.episodes[1:])
    assert not Comparison(ARM, other_time, "x").same_pushes  # both survived: the push must have come at the same time


def test_push_protocol_is_validated() -> None:
    for bad in ({"interval": (0.0, 1.0)}, {"interval": (1.6, 1.2)}, {"duration": 0.0}, {"force": -1.0}):
        with pytest.raises(ValueError, match="bad push protocol"):
            PushProtocol(**bad)
    PushProtocol(force=0.0, interval=(1.2, 1.2), episode_seconds=4.4)  # the edges that are allowed
    with pytest.raises(ValueError, match=r"episode_seconds must be >= interval\[1\] \+ duration \+ 3 = 4\.80 s"):
        PushProtocol(episode_seconds=4.7)  # the latest push would end 2.9 s before the end
    with pytest.raises(ValueError, match=r"interval\[1\] must be < 2\*interval\[0\] \+ duration = 2\.25 s"):
        PushProtocol(interval=(1.0, 2.25), duration=0.25, episode_seconds=6.0)  # a second push could come first
    assert PushProtocol(interval=(1.0, 1.5), duration=0.25, episode_seconds=10.0).episode_seconds == 10.0  # longer: fine


def test_sim_to_sim_cells_and_their_summary() -> None:
    cell = Cell(episodes=4, successes=3, simulated_s=30.0, wall_s=8.0, failed_seeds=[7, 2], fall_after_push_s=[2.5])
    assert cell.success_rate == 0.75
    assert cell.summary() == {"episodes": 4, "successes": 3, "success_rate": 0.75, "mean_survival_s": 7.5,
                              "wall_s_per_episode": 2.0, "failed_seeds": [2, 7], "falls": 1, "fall_after_push_s": [2.5]}  # fmt: skip
    empty = Cell()
    assert math.isnan(empty.success_rate) and empty.summary()["mean_survival_s"] is None
    assert empty.summary()["wall_s_per_episode"] is None
    setting = PushSetting(force=50.0, duration=0.1, interval=(1.0, 2.0))
    assert setting.sim2real(10.0) == {"pushes": {"force": [50.0, 50.0], "duration": 0.1, "interval": [1.0, 2.0], "horizon": 10.0}}
    assert setting.episode_seconds(10.0) == pytest.approx(10.0 + 0.1 + SETTLE_AFTER_PUSH_S)


def test_sim_to_sim_refuses_bad_requests() -> None:
    with pytest.raises(ValueError, match="episodes must be >= 1 and seconds > 0, got 0, 1.0"):
        evaluate(episodes=0, seconds=1.0)
    with pytest.raises(ValueError, match="episodes must be >= 1 and seconds > 0, got 1, 0.0"):
        evaluate(episodes=1, seconds=0.0)
    with pytest.raises(ValueError, match=r"unknown conditions \['moon'\]"):
        evaluate(episodes=1, seconds=1.0, conditions=("mujoco_nominal", "moon"))


def test_sim_to_sim_chunks_and_workers_do_not_change_the_result(g1_model) -> None:
    """Six episodes: two chunks of seeds (5 + 1); in this process or on two workers, the same cells."""
    kwargs = dict(episodes=6, seconds=0.7, pushes=PushSetting(force=30.0, duration=0.1, interval=(0.6, 0.65)), seed=11,
                  conditions=("mujoco_nominal",), env_kwargs={"model": g1_model})  # fmt: skip
    import time

    before = time.perf_counter()
    here = evaluate(workers=0, **kwargs)["wbc_only"]["mujoco_nominal"]
    elapsed = time.perf_counter() - before
    assert 0.0 < here.wall_s <= elapsed  # the episodes' own wall time, measured inside the call
    pooled = evaluate(workers=2, **kwargs)["wbc_only"]["mujoco_nominal"]
    assert (here.episodes, here.successes, here.failed_seeds) == (6, 6, [])
    assert here.simulated_s == pytest.approx(6 * (0.7 + 0.1 + SETTLE_AFTER_PUSH_S))
    assert (pooled.episodes, pooled.successes, pooled.simulated_s) == (here.episodes, here.successes, here.simulated_s)


def test_sim_to_sim_runs_the_policy_in_the_policy_row(tmp_path, g1_model) -> None:
    """The policy row runs the policy: one whose output is NaN is refused at its first step (the
    WBC row alone, same seeds, runs through)."""
    import gymnasium
    import numpy as np

    from giwbc.policy import MlpWeights, export_onnx
    from giwbc.tasks import InvalidActionError

    env = gymnasium.make("giwbc/G1Balance-v0", model=g1_model).unwrapped
    sizes = (env.observation_space.shape[0], 8, env.action_space.shape[0])
    mlp = MlpWeights(((np.zeros((8, sizes[0])), np.zeros(8)), (np.zeros((sizes[2], 8)), np.full(sizes[2], np.nan))))
    metadata = {**env.describe(), "env_id": "giwbc/G1Balance-v0", "env_kwargs": {}}
    policy = export_onnx(tmp_path / "nan.onnx", mlp, metadata, action_low=env.action_space.low, action_high=env.action_space.high)
    common = dict(episodes=1, seconds=0.1, pushes=PushSetting(force=0.0, duration=0.05, interval=(5.0, 6.0)), workers=0, seed=3,
                  conditions=("mujoco_nominal",), env_kwargs={"model": g1_model})  # fmt: skip
    assert evaluate(**common)["wbc_only"]["mujoco_nominal"].successes == 1
    with pytest.raises(InvalidActionError, match="non-finite"):
        evaluate(policy=policy, **common)


def test_evaluation_runs_the_environment_and_the_policy_it_is_given(tmp_path) -> None:
    """The arm's options reach the environment (a joint-PD controller scores differently from the
    WBC on the same seed), and a policy arm runs its policy (a NaN policy is refused at once)."""
    import numpy as np

    from giwbc.apps.evaluation import DEFAULT_ENV_KWARGS
    from giwbc.policy import MlpWeights, export_onnx
    from giwbc.tasks import InvalidActionError
    from giwbc.apps.training import describe_env

    (wbc,) = run_episodes(None, protocol=GENTLE, episodes=1, seed=5, workers=1).episodes
    (pd,) = run_episodes(None, env_kwargs={"controller": "pd"}, protocol=GENTLE, episodes=1, seed=5, workers=1).episodes
    assert pd.episode_return != wbc.episode_return
    env_kwargs = {**DEFAULT_ENV_KWARGS, "max_episode_steps": 1000}
    described = describe_env("giwbc/G1Balance-v0", env_kwargs)
    n_obs, n_act = len(described["observation_names"]), len(described["action_names"])
    weights = MlpWeights(((np.zeros((8, n_obs)), np.zeros(8)), (np.zeros((n_act, 8)), np.full(n_act, np.nan))))
    policy = export_onnx(tmp_path / "nan.onnx", weights, {**described, "env_id": "giwbc/G1Balance-v0", "env_kwargs": env_kwargs})
    with pytest.raises(InvalidActionError, match="non-finite"):
        run_episodes(policy, protocol=GENTLE, episodes=1, seed=5, workers=1)
