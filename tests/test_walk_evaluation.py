"""Walking push-recovery evaluation: tracking metric, protocol, paired statistics, the command (short episodes)."""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
import math

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from giwbc.apps.evaluation import ArmResult, Comparison, EpisodeResult, compare, velocity_tracking_rms  # noqa: E402
from giwbc.apps.walk_evaluation import WalkProtocol, add_evaluate_command, paired_tracking, tracking_summary  # noqa: E402
from giwbc.policy import MlpWeights, export_onnx  # noqa: E402

# 0.1 s push in [1.2, 1.3] s of a walking episode that runs on the 3 s settle window after it, forward commands only.
SHORT = WalkProtocol(force=30.0, duration=0.1, interval=(1.2, 1.3), episode_seconds=4.4, commands=((0.2, 0.3), (0.0, 0.0), (0.0, 0.0)))


def test_tracking_rms_of_known_motions() -> None:
    times = np.arange(0, 5.0001, 0.02)
    yaw = np.full(len(times), math.pi / 2)  # heading +y: a body-frame vx moves along world +y
    xy = np.stack([np.zeros(len(times)), 0.25 * times], axis=1)
    commands = np.tile([0.3, 0.0, 0.0], (len(times), 1))
    assert velocity_tracking_rms(times, xy, yaw, commands) == pytest.approx(0.05)
    wobble = xy + np.stack([0.03 * np.sin(2 * math.pi * times), np.zeros(len(times))], axis=1)  # 1 Hz sway: averages out
    assert velocity_tracking_rms(times, wobble, yaw, commands) == pytest.approx(0.05, abs=1e-9)
    commands[125:] = [0.25, 0.0, 0.0]  # from 2.5 s: the command is met; the window across the change is skipped
    assert velocity_tracking_rms(times, xy, yaw, commands) == pytest.approx(math.sqrt(0.05**2 / 3))
    assert math.isnan(velocity_tracking_rms(times[:40], xy[:40], yaw[:40], commands[:40]))


def test_walk_protocol_draws_one_command_per_episode() -> None:
    overrides = SHORT.env_overrides({"residuals": ["step"], "commands": {"vx": [-0.1, 0.1]}}, 50.0)
    assert overrides["commands"]["vx"] == [0.2, 0.3] and overrides["commands"]["standing"] == 0.0
    assert overrides["commands"]["interval"][0] > SHORT.episode_seconds and overrides["max_episode_steps"] == 220
    assert overrides["sim2real"]["pushes"]["force"] == [30.0, 30.0]
    assert overrides["sim2real"]["pushes"]["horizon"] == pytest.approx(2.5)  # no second push: it could start at 2.5 s at the earliest
    assert WalkProtocol().episode_seconds == pytest.approx(2.0 + 0.2 + 3.0)  # the latest push's end + the settle window
    with pytest.raises(ValueError, match="judged 3 s after the push ends"):
        replace(SHORT, episode_seconds=4.3)
    with pytest.raises(ValueError):
        WalkProtocol(commands=((0.3, 0.1), (0.0, 0.0), (0.0, 0.0)))


def _episode(seed: int, success: bool, tracking: float) -> EpisodeResult:
    return EpisodeResult(seed, success, success, 2.0, 0.0, 0.1, 1.0, (1.0, 0.0, 0.0), 0.0, tracking)


def test_paired_tracking_statistics() -> None:
    rng = np.random.default_rng(0)
    base = rng.uniform(0.05, 0.2, 30)
    wbc = ArmResult("wbc", SHORT, tuple(_episode(i, True, b) for i, b in enumerate(base)))
    better = ArmResult("p", SHORT, tuple(_episode(i, i != 0, b - 0.02) for i, b in enumerate(base)))
    t = paired_tracking(Comparison(wbc, better, "giwbc/G1Walk-v0"))
    assert t.n == 29  # the episode the policy lost is not paired
    assert t.mean_difference == pytest.approx(-0.02) and t.difference_ci[1] < 0 and t.wilcoxon_p < 1e-5
    same = paired_tracking(Comparison(wbc, wbc, "giwbc/G1Walk-v0"))
    assert same.mean_difference == 0.0 and same.wilcoxon_p == 1.0


def _zero_walk_policy(tmp_path, env_kwargs):
    from giwbc.apps.training import describe_env

    described = describe_env("giwbc/G1Walk-v0", env_kwargs)
    n_obs, n_act = len(described["observation_names"]), len(described["action_names"])
    weights = MlpWeights(((np.zeros((8, n_obs)), np.zeros(8)), (np.zeros((n_act, 8)), np.zeros(n_act))))
    return export_onnx(tmp_path / "zero.onnx", weights, {**described, "env_id": "giwbc/G1Walk-v0", "env_kwargs": env_kwargs})


def test_zero_policy_walks_like_the_walker_and_the_command_reports(tmp_path, capsys) -> None:
    policy = _zero_walk_policy(tmp_path, {"residuals": ["step", "com"], "sim2real": {"pushes": None}})
    comparison = compare(policy, protocol=SHORT, episodes=2, seed=4, workers=2)
    assert comparison.same_pushes
    for wbc, residual in zip(comparison.wbc.episodes, comparison.residual.episodes):
        assert wbc == residual and wbc.success and 1.2 <= wbc.push_time <= 1.34
        assert 0.0 < wbc.tracking_rms < 0.3
        # Per tick, the sway within each step counts: above the 1-s window figure, below a walk's worst.
        assert wbc.tracking_rms < wbc.tracking_rms_per_tick_heading_xy < 0.4
        assert wbc.tracking_mean_abs_per_tick_heading_xy < wbc.tracking_rms_per_tick_heading_xy
        assert 0.0 < wbc.yaw_rate_mean_abs_per_tick < wbc.yaw_rate_rms_per_tick < 0.5
    parser = argparse.ArgumentParser()
    add_evaluate_command(parser.add_subparsers())
    args = parser.parse_args(["evaluate", "--protocol", "walk", "--policy", str(policy), "--episodes", "1", "--workers", "1",
                              "--force", "30", "--duration", "0.1", "--interval", "1.2", "1.3",
                              "--commands", "0.2", "0.3", "0", "0", "0", "0", "--seed", "4", "--json"])
    assert args.run(args) == 0
    (summary,) = json.loads(capsys.readouterr().out)["comparisons"]
    assert summary["paired"]["saved"] == summary["paired"]["lost"] == 0 and summary["tracking"]["n"] == 1
    assert summary["tracking"]["wbc_mean"] == pytest.approx(comparison.wbc.episodes[0].tracking_rms)
    per_tick = summary["tracking_per_tick"]["wbc"]
    assert per_tick["tracking_rms_per_tick_heading_xy"] == pytest.approx(comparison.wbc.episodes[0].tracking_rms_per_tick_heading_xy)
    assert summary["wbc"]["mean_survival_time_s"] == pytest.approx(1.3 + 0.1 + 3.0)  # the default episode: push end + 3 s


def test_cached_arms_give_the_same_comparison(tmp_path) -> None:
    from giwbc.apps.walk_evaluation import cached_arm, compare_cached

    env_kwargs = {"residuals": ["step"], "sim2real": {"pushes": None}}
    policy = _zero_walk_policy(tmp_path, env_kwargs)
    cache = tmp_path / "cache"
    protocol = SHORT
    alone = cached_arm(cache, None, env_id="giwbc.envs:giwbc/G1Walk-v0", env_kwargs=env_kwargs, protocol=protocol, episodes=1, seed=9, workers=1)
    assert len(list(cache.glob("arm_*.json"))) == 1
    first = compare_cached(policy, cache, protocol=protocol, episodes=1, seed=9, workers=1)
    assert len(list(cache.glob("arm_*.json"))) == 2  # the walker-alone arm came from the cache
    again = compare_cached(policy, cache, protocol=protocol, episodes=1, seed=9, workers=1)
    assert first.wbc.episodes == alone.episodes == again.wbc.episodes and first.residual.episodes == again.residual.episodes
    assert first.wbc.episodes == first.residual.episodes  # the zero policy is the walker alone
    other = compare_cached(policy, cache, protocol=replace(protocol, force=35.0), episodes=1, seed=9, workers=1)
    assert len(list(cache.glob("arm_*.json"))) == 4 and other.wbc.protocol.force == 35.0


def test_tracking_rms_divides_by_the_window_actually_spanned() -> None:
    """Samples every 0.03 s: a 1-s window spans 1.02 s; the window average is still the speed."""
    times = np.arange(0, 5.0001, 0.03)
    xy = np.stack([0.25 * times, np.zeros(len(times))], axis=1)
    commands = np.tile([0.3, 0.0, 0.0], (len(times), 1))
    assert velocity_tracking_rms(times, xy, np.zeros(len(times)), commands) == pytest.approx(0.05, abs=1e-12)


def test_walk_protocol_commands_are_what_the_walk_task_reads() -> None:
    """The overrides build the walk task's command ranges (a fixed command is a range of one
    value), held past the episode's end; a malformed range is refused with what was given."""
    from giwbc.tasks.walk import CommandRanges

    fixed = WalkProtocol(commands=((0.3, 0.3), (-0.1, 0.1), (0.2, 0.2)))
    ranges = CommandRanges(**fixed.env_overrides({}, 50.0)["commands"])
    assert (ranges.vx, ranges.vy, ranges.yaw_rate, ranges.standing) == ((0.3, 0.3), (-0.1, 0.1), (0.2, 0.2), 0.0)
    assert ranges.interval[0] > fixed.episode_seconds and ranges.horizon > fixed.episode_seconds
    with pytest.raises(ValueError, match=r"^commands must be three \(low, high\) ranges \(vx, vy, yaw_rate\), got \(\(0\.3, 0\.1\),\)$"):
        WalkProtocol(commands=((0.3, 0.1),))


def test_paired_tracking_intervals_belong_to_their_arm_and_a_zero_mean_difference_is_not_significant() -> None:
    rng = np.random.default_rng(1)
    base = rng.uniform(0.05, 0.1, 40)
    wbc = ArmResult("wbc", SHORT, tuple(_episode(i, True, b) for i, b in enumerate(base)))
    worse = ArmResult("p", SHORT, tuple(_episode(i, True, b + 0.2) for i, b in enumerate(base)))
    t = paired_tracking(Comparison(wbc, worse, "giwbc/G1Walk-v0"))
    assert t.wbc_ci[0] < t.wbc_mean < t.wbc_ci[1] < t.residual_ci[0] < t.residual_mean < t.residual_ci[1]
    noisy = ArmResult("p", SHORT, tuple(_episode(i, True, b + 0.01 * (-1) ** i) for i, b in enumerate(base)))
    assert paired_tracking(Comparison(wbc, noisy, "giwbc/G1Walk-v0")).wilcoxon_p > 0.05  # +-0.01 alternately: no shift
    summary = tracking_summary(wbc)
    assert summary["tracking_episodes"] == 40 and summary["mean_tracking_rms_window_1s"] == pytest.approx(base.mean())
    low, high = summary["mean_tracking_rms_window_1s_95ci"]
    assert low < base.mean() < high
    assert tracking_summary(wbc) == summary  # a seeded bootstrap: the same interval every time
    fallen = ArmResult("wbc", SHORT, wbc.episodes + (_episode(40, False, 5.0),))  # fell, though its tracking is finite
    assert tracking_summary(fallen) == summary


def test_per_tick_figures_pool_over_the_surviving_episodes() -> None:
    """Two survivors with per-tick RMS 0.1 and 0.2 (equal lengths): pooled RMS sqrt((0.01 + 0.04) / 2), mean absolute the
    mean; a fallen episode does not count."""
    def with_ticks(seed: int, survived: bool, rms: float, mean_abs: float) -> EpisodeResult:
        return replace(_episode(seed, survived, 0.05), tracking_rms_per_tick_heading_xy=rms, tracking_mean_abs_per_tick_heading_xy=mean_abs,
                       yaw_rate_rms_per_tick=2 * rms, yaw_rate_mean_abs_per_tick=2 * mean_abs)

    arm = ArmResult("wbc", SHORT, (with_ticks(0, True, 0.1, 0.08), with_ticks(1, True, 0.2, 0.12), with_ticks(2, False, 3.0, 3.0)))
    summary = tracking_summary(arm)
    assert summary["tracking_rms_per_tick_heading_xy"] == pytest.approx(math.sqrt(0.025))
    assert summary["tracking_mean_abs_per_tick_heading_xy"] == pytest.approx(0.1)
    assert summary["yaw_rate_rms_per_tick"] == pytest.approx(2 * math.sqrt(0.025))
    assert summary["yaw_rate_mean_abs_per_tick"] == pytest.approx(0.2)
