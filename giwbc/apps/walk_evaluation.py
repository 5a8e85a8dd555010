"""Seeded push recovery *while walking*, and velocity tracking: a residual policy against the walker alone.

The protocol (:class:`WalkProtocol`) is :mod:`giwbc.apps.evaluation`'s with a walking episode: a
velocity command drawn per episode (seeded, the same in both arms) and held from the start, one
push of ``force`` N in a uniform random horizontal direction for ``duration`` s at a uniform time
in ``interval`` (the gait is established by then). Success as there (not fallen, tilt at the end
under ``upright_tilt``, the episode running on at least
:data:`~giwbc.locomotion.push_scoring.SETTLE_AFTER_PUSH_S` after the push ends), compared with the
exact McNemar test on the discordant pairs. Velocity tracking, two ways, from 1 s on, the push
included: each episode's RMS of the 1-s **window-averaged** base velocity against the command
(:func:`~giwbc.apps.evaluation.velocity_tracking_rms`: the gait's sway averages out), compared on
the episodes both arms survive with the Wilcoxon signed-rank test (scipy) and a bootstrap 95 %
interval of the mean paired difference; and **per tick** (every agent step, 50 Hz: mjlab's
``track_lin_vel_xy``, the instantaneous base velocity in the heading frame,
:mod:`giwbc.locomotion.tracking`), RMS and mean absolute, xy and yaw rate.

``giwbc evaluate --protocol walk [--policy P]`` runs it (``--protocol stand``, the default, is the
standing protocol of :mod:`giwbc.apps.evaluation`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from giwbc.apps.evaluation import (
    DEFAULT_ENV_ID,
    ArmResult,
    Comparison,
    EpisodeResult,
    PushProtocol,
    arm_per_plant,
    format_falls,
    format_per_plant,
    settled_episode_seconds,
    success_rule,
    compare,
    compare_forces,
    format_table,
    policy_env,
    run_episodes,
    run_evaluate_command,
    sweep,
)
from giwbc.apps.evaluation import add_evaluate_command as add_stand_evaluate_command
from giwbc.apps.evaluation import check_plant
from giwbc.apps.arguments import number
from giwbc.distributed import RayRunner, connect
from giwbc.errors import ConfigError
from giwbc.locomotion.push_scoring import SETTLE_AFTER_PUSH_S
from giwbc.policy import OnnxPolicy, PolicyFormatError

WALK_ENV_ID = "giwbc/G1Walk-v0"
WALK_ENV_KWARGS: dict[str, Any] = {"residuals": ["step"]}  # the zero residual: any blocks give the walker alone


@dataclass(frozen=True)
class WalkProtocol(PushProtocol):
    """One push per walking episode; ``commands``: the ``(low, high)`` ranges of vx, vy (m/s) and
    yaw rate (rad/s) the episode's command is drawn from (uniform), held the whole episode."""

    force: float = 80.0
    interval: tuple[float, float] = (1.8, 2.0)  # from the 4th step on (start-up: 0.3 s weight shift, 0.46 s steps)
    episode_seconds: float = round(2.0 + 0.2 + SETTLE_AFTER_PUSH_S, 6)  # the latest push's end + the settle window
    commands: tuple[tuple[float, float], tuple[float, float], tuple[float, float]] = ((0.1, 0.4), (-0.1, 0.1), (-0.3, 0.3))

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.commands) != 3 or any(len(r) != 2 or not r[0] <= r[1] for r in self.commands):
            raise ValueError(f"commands must be three (low, high) ranges (vx, vy, yaw_rate), got {self.commands}")

    def env_overrides(self, base_kwargs: dict[str, Any], agent_hz: float) -> dict[str, Any]:
        (vx, vy, wz) = ([float(x) for x in r] for r in self.commands)
        horizon = self.episode_seconds + 1.0
        commands = {"vx": vx, "vy": vy, "yaw_rate": wz, "standing": 0.0, "interval": [horizon, horizon], "horizon": horizon}
        return {**super().env_overrides(base_kwargs, agent_hz), "commands": commands}


def _finite(value: float | None) -> bool:
    return value is not None and math.isfinite(value)


def _bootstrap_mean(values: np.ndarray, resamples: int, rng: np.random.Generator) -> tuple[float, float]:
    if len(values) == 0:
        return (math.nan, math.nan)
    means = values[rng.integers(0, len(values), (resamples, len(values)))].mean(axis=1)
    return (float(np.quantile(means, 0.025)), float(np.quantile(means, 0.975)))


@dataclass(frozen=True)
class TrackingComparison:
    """Velocity-tracking RMS (m/s) of both arms on the episodes both survive (paired)."""

    n: int
    wbc_mean: float
    wbc_ci: tuple[float, float]
    residual_mean: float
    residual_ci: tuple[float, float]
    mean_difference: float  # residual − walker alone: < 0 means the residual tracks better
    difference_ci: tuple[float, float]
    wilcoxon_p: float


def paired_tracking(comparison: Comparison, resamples: int = 10_000, seed: int = 0) -> TrackingComparison:
    """The paired tracking comparison (bootstrap intervals from a seeded generator)."""
    pairs = np.array([(a.tracking_rms, b.tracking_rms) for a, b in zip(comparison.wbc.episodes, comparison.residual.episodes)
                      if a.survived and b.survived and _finite(a.tracking_rms) and _finite(b.tracking_rms)]).reshape(-1, 2)
    rng = np.random.default_rng(seed)
    difference = pairs[:, 1] - pairs[:, 0]
    p = float(stats.wilcoxon(pairs[:, 1], pairs[:, 0]).pvalue) if np.any(difference != 0) else 1.0
    mean = (lambda x: float(np.mean(x)) if len(x) else math.nan)
    return TrackingComparison(len(pairs), mean(pairs[:, 0]), _bootstrap_mean(pairs[:, 0], resamples, rng), mean(pairs[:, 1]),
                              _bootstrap_mean(pairs[:, 1], resamples, rng), mean(difference),
                              _bootstrap_mean(difference, resamples, rng), p)


PER_TICK_KEYS = ("tracking_rms_per_tick_heading_xy", "tracking_mean_abs_per_tick_heading_xy", "yaw_rate_rms_per_tick",
                 "yaw_rate_mean_abs_per_tick")


def tracking_summary(arm: ArmResult) -> dict[str, Any]:
    """Tracking over the surviving episodes: the mean of their 1-s window RMS (``mean_tracking_rms_window_1s``, with a
    bootstrap 95 % interval), and the per-tick heading-frame figures pooled over their agent steps
    (episodes of equal length: the RMS of the RMS, the mean of the means)."""
    survivors = [e for e in arm.episodes if e.survived]
    values = np.array([e.tracking_rms for e in survivors if _finite(e.tracking_rms)])
    per_tick: dict[str, float] = {}
    for key in PER_TICK_KEYS:
        figures = np.array([getattr(e, key) for e in survivors if _finite(getattr(e, key))])
        pooled = (np.sqrt(np.mean(figures**2)) if "rms" in key else np.mean(figures)) if len(figures) else math.nan
        per_tick[key] = float(pooled)
    return {"tracking_episodes": len(values), "mean_tracking_rms_window_1s": float(values.mean()) if len(values) else math.nan,
            "mean_tracking_rms_window_1s_95ci": list(_bootstrap_mean(values, 10_000, np.random.default_rng(0))), **per_tick}


def walk_summary(comparison: Comparison) -> dict[str, Any]:
    return {**comparison.summary(), "tracking": asdict(paired_tracking(comparison)),
            "tracking_per_tick": {"wbc": _per_tick(comparison.wbc), "residual": _per_tick(comparison.residual)}}


def _per_tick(arm: ArmResult) -> dict[str, float]:
    summary = tracking_summary(arm)
    return {key: summary[key] for key in PER_TICK_KEYS}


def format_per_tick(arm: ArmResult) -> str:
    """The per-tick heading-frame figures of an arm, one line."""
    t = tracking_summary(arm)
    return (f"{arm.name} at {arm.protocol.force:g} N, per tick (heading frame, 50 Hz): xy RMS "
            f"{t['tracking_rms_per_tick_heading_xy']:.3f}, mean abs {t['tracking_mean_abs_per_tick_heading_xy']:.3f} m/s; "
            f"yaw rate RMS {t['yaw_rate_rms_per_tick']:.3f}, mean abs {t['yaw_rate_mean_abs_per_tick']:.3f} rad/s")


# --- arms kept on disk ----------------------------------------------------------------------------
def _arm_key(policy_path: str | os.PathLike[str] | None, env_id: str, env_kwargs: dict[str, Any], protocol: PushProtocol,
             episodes: int, seed: int) -> str:
    """What an arm's episodes depend on: the policy file's bytes (none: the zero residual), the
    environment and its options, the protocol, the seeds. (Not the number of workers: results do
    not depend on it.)"""
    policy = hashlib.sha256(Path(policy_path).read_bytes()).hexdigest() if policy_path is not None else None
    spec = {"policy": policy, "env_id": env_id.split(":")[-1], "env_kwargs": env_kwargs, "protocol": asdict(protocol),
            "protocol_type": type(protocol).__name__, "episodes": episodes, "seed": seed}
    return hashlib.sha256(json.dumps(spec, sort_keys=True, default=list).encode()).hexdigest()[:24]


def cached_arm(cache: str | os.PathLike[str], policy_path: str | os.PathLike[str] | None, *, env_id: str, env_kwargs: dict[str, Any],
               protocol: PushProtocol, episodes: int, seed: int, workers: int = 2) -> ArmResult:
    """:func:`~giwbc.apps.evaluation.run_episodes`, its episodes kept in ``cache`` (a folder) under
    a key of everything they depend on: the walker-alone arm of a force and seeds is run once for
    every policy compared on them."""
    path = Path(cache) / f"arm_{_arm_key(policy_path, env_id, env_kwargs, protocol, episodes, seed)}.json"
    name = "wbc" if policy_path is None else os.path.basename(str(policy_path))
    if path.is_file():
        rows = json.loads(path.read_text())
        return ArmResult(name, protocol, tuple(EpisodeResult(**{**row, "push_force": tuple(row["push_force"])}) for row in rows))
    arm = run_episodes(policy_path, env_id=env_id, env_kwargs=env_kwargs, protocol=protocol, episodes=episodes, seed=seed, workers=workers)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps([asdict(e) for e in arm.episodes]))
    return arm


def compare_cached(policy_path: str | os.PathLike[str], cache: str | os.PathLike[str], *, protocol: PushProtocol, episodes: int,
                   seed: int, workers: int = 2) -> Comparison:
    """:func:`~giwbc.apps.evaluation.compare` with both arms kept in ``cache`` (same results)."""
    env_id, env_kwargs = policy_env(policy_path)
    env_kwargs = {k: v for k, v in env_kwargs.items() if k != "max_episode_steps"}
    common = {"env_id": env_id, "env_kwargs": env_kwargs, "protocol": protocol, "episodes": episodes, "seed": seed, "workers": workers}
    return Comparison(cached_arm(cache, None, **common), cached_arm(cache, policy_path, **common), env_id, env_kwargs)


# --- command line ------------------------------------------------------------------------------
def add_evaluate_command(commands: Any) -> None:
    """``giwbc evaluate`` (:mod:`giwbc.apps.evaluation`) with ``--protocol stand|walk``."""
    add_stand_evaluate_command(commands)
    parser = commands.choices["evaluate"]
    parser.add_argument("--protocol", choices=("stand", "walk"), default="stand",
                        help=f"stand: the standing push protocol; walk: pushes while walking on commands ({WALK_ENV_ID})")
    parser.add_argument("--commands", type=number(-5.0, 5.0, unit="m/s or rad/s"), nargs=6, default=None,
                        metavar=("VX0", "VX1", "VY0", "VY1", "WZ0", "WZ1"),
                        help=f"walk: ranges (low high) of vx, vy (m/s) and yaw rate (rad/s) each episode's command is drawn from "
                             f"(default {[x for r in WalkProtocol.commands for x in r]})")
    parser.add_argument("--cache", default=None, help="walk: keep each arm's episodes in this folder (the walker-alone arm "
                        "is then run once for all policies compared on the same force and seeds)")
    parser.set_defaults(run=run_evaluate)


def check_evaluate_args(args: Any) -> None:
    """ConfigError (PolicyFormatError for an unreadable policy) for options that argparse's types cannot
    judge alone: the push within the episode, ordered ranges, a policy or environment of the protocol's kind."""
    walking = getattr(args, "protocol", "stand") == "walk"
    protocol = WalkProtocol if walking else PushProtocol
    env_id = WALK_ENV_ID if walking else DEFAULT_ENV_ID
    low, high = args.interval or protocol.interval
    episode = args.episode_seconds or settled_episode_seconds((low, high), args.duration)
    if low > high:
        raise ConfigError(f"--interval MIN MAX: MIN {low:g} s is above MAX {high:g} s")
    if episode < settled_episode_seconds((low, high), args.duration) - 1e-9:
        raise ConfigError(f"a push starting as late as {high:g} s for {args.duration:g} s needs an episode of at least "
                          f"{settled_episode_seconds((low, high), args.duration):g} s (success is judged {SETTLE_AFTER_PUSH_S:g} s "
                          f"after the push ends), not {episode:g} s (lower --interval or raise --episode-seconds)")
    if getattr(args, "commands", None) is not None:
        for name, (lo, hi) in zip(("vx", "vy", "yaw rate"), zip(args.commands[::2], args.commands[1::2])):
            if lo > hi:
                raise ConfigError(f"--commands: the {name} range [{lo:g}, {hi:g}] is reversed")
    if args.policy is not None:
        trained_on = OnnxPolicy(args.policy).env_id
        if trained_on != env_id:
            raise ConfigError(f"{args.policy} is a policy for {trained_on}: the {'walk' if walking else 'stand'} protocol evaluates "
                              f"policies for {env_id}" + ("" if walking else " (for a walking policy: --protocol walk)"))
    elif args.env is not None and args.env != env_id:
        raise ConfigError(f"--env {args.env}: the {'walk' if walking else 'stand'} protocol runs on {env_id}")
    try:
        options = json.loads(args.env_kwargs)
    except json.JSONDecodeError as error:
        raise ConfigError(f"--env-kwargs is not JSON: {error}") from None
    if not isinstance(options, dict):
        raise ConfigError(f"--env-kwargs must be a JSON object, got {args.env_kwargs}")


def run_evaluate(args: Any) -> int:
    check_evaluate_args(args)
    if getattr(args, "protocol", "stand") != "walk":
        return run_evaluate_command(args)

    connection = None
    try:
        ranges = WalkProtocol.commands if args.commands is None else tuple(zip(args.commands[::2], args.commands[1::2]))
        interval = tuple(args.interval or WalkProtocol.interval)
        protocol = WalkProtocol(force=args.force[0], duration=args.duration, interval=interval,  # type: ignore[arg-type]
                                episode_seconds=args.episode_seconds or settled_episode_seconds(interval, args.duration),  # type: ignore[arg-type]
                                upright_tilt=args.upright_tilt,
                                commands=ranges, plant=check_plant(args))  # type: ignore[arg-type]
        connection = connect(args.ray) if getattr(args, "ray", None) else None
        runner = RayRunner(connection) if connection is not None else None
        workers = args.workers or (runner.cpus if runner is not None else 2)
        common = {"episodes": args.episodes, "seed": args.seed, "workers": workers, "runner": runner}
        comparisons: list[Comparison] = []
        if args.policy is None:
            env_kwargs = json.loads(args.env_kwargs) or WALK_ENV_KWARGS
            if args.cache and runner is None:
                rows = [cached_arm(args.cache, None, env_id=args.env or WALK_ENV_ID, env_kwargs=env_kwargs, protocol=replace(protocol, force=f),
                                   episodes=args.episodes, seed=args.seed, workers=workers) for f in args.force]
            else:
                rows = sweep(args.force, env_id=args.env or WALK_ENV_ID, env_kwargs=env_kwargs, protocol=protocol, **common)
            summary: dict[str, Any] = {"env_id": args.env or WALK_ENV_ID,
                                       "arms": [r.summary() | tracking_summary(r) | {"force": r.protocol.force}
                                                | ({"per_plant": arm_per_plant(r)} if arm_per_plant(r) else {}) for r in rows]}
        else:
            protocols = [replace(protocol, force=force) for force in args.force]
            if runner is not None:
                comparisons = compare_forces(args.policy, protocols, **common)
            elif args.cache:
                comparisons = [compare_cached(args.policy, args.cache, protocol=p, episodes=args.episodes, seed=args.seed,
                                              workers=workers) for p in protocols]
            else:
                comparisons = [compare(args.policy, protocol=p, **common) for p in protocols]
            rows = [arm for c in comparisons for arm in (c.wbc, c.residual)]
            summary = {"comparisons": [walk_summary(c) for c in comparisons]}
    except (PolicyFormatError, FileNotFoundError, ValueError) as error:
        print(f"giwbc evaluate: error: {error}", file=sys.stderr)
        return 2
    finally:
        if connection is not None:
            connection.close()
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"walking on a command drawn per episode from vx, vy, yaw rate in {[list(r) for r in protocol.commands]}; one push "
          f"per episode: {protocol.duration} s, random horizontal direction, start uniform in {list(protocol.interval)} s; "
          f"episodes of {protocol.episode_seconds:g} s; {success_rule(protocol)}; "
          f"seeds {args.seed}..{args.seed + args.episodes - 1}")
    print(format_table(rows))
    print(format_falls(rows))
    for row in rows:
        print(format_per_tick(row))
        not_started = row.summary()["not_started"]
        if not_started:
            print(f"{row.name} at {row.protocol.force:g} N: {not_started} of {row.n} episodes never started (the estimator did "
                  "not calibrate at reset on the drawn plant): counted as failures, the same in every arm")
    if args.policy is None:
        for row in rows:
            t = tracking_summary(row)
            low, high = t["mean_tracking_rms_window_1s_95ci"]
            print(f"tracking at {row.protocol.force:g} N, 1-s window averages: RMS {t['mean_tracking_rms_window_1s']:.3f} m/s "
                  f"[{low:.3f}, {high:.3f}] over {t['tracking_episodes']} surviving episodes")
        return 0
    print("same pushes in both arms: " + ", ".join(str(c.same_pushes) for c in comparisons))
    for c in comparisons:
        t = paired_tracking(c)
        print(f"paired at {c.wbc.protocol.force:g} N: the residual saves {c.saved}, loses {c.lost} (exact McNemar p = "
              f"{c.paired_p_value:.3g}); tracking RMS of 1-s window averages over the {t.n} episodes both survive: walker alone {t.wbc_mean:.3f} "
              f"[{t.wbc_ci[0]:.3f}, {t.wbc_ci[1]:.3f}], residual {t.residual_mean:.3f} [{t.residual_ci[0]:.3f}, "
              f"{t.residual_ci[1]:.3f}] m/s, difference {t.mean_difference:+.3f} [{t.difference_ci[0]:+.3f}, "
              f"{t.difference_ci[1]:+.3f}] (Wilcoxon p = {t.wilcoxon_p:.3g})")
        if format_per_plant(c):
            print(format_per_plant(c))
    return 0
