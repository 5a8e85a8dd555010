"""Seeded push-recovery evaluation: a residual policy against the controller alone (zero residual).

Both arms run the same environment (the one the policy's metadata names, with its options) over
the same seeds, so each episode has the same initial state and the same push (time, direction,
magnitude) in both arms; :attr:`Comparison.same_pushes` checks that from what the runtime reports.
The push protocol (:class:`PushProtocol`) replaces the environment's pushes: one push of ``force``
N in a uniform random horizontal direction for ``duration`` s, starting at a uniform time in
``interval`` s (the push schedule ends before a second push could start), in an episode of
``episode_seconds``: at least :data:`~giwbc.locomotion.push_scoring.SETTLE_AFTER_PUSH_S` (3 s)
past the latest push's end, so that a robot toppling slowly after the push falls inside the episode.
An episode *survives* if it is not terminated (pelvis too low or tilted past the task's limit) before
the time limit, and *succeeds* if it survives with the pelvis tilt at the end under ``upright_tilt``
(a robot falling over at the time limit is not a success), as
:func:`~giwbc.locomotion.push_scoring.judge_push` judges it; each fall is reported with its time
after the push ended.

Episodes are split over worker processes (fork), or over Ray tasks on a cluster (``runner``, see
:mod:`giwbc.distributed`); results do not depend on the number of workers nor on where they ran.
Needs onnxruntime for a policy arm, not torch.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from giwbc.apps.arguments import add_command, integer, number, policy_file, seconds, seed
from giwbc.apps.plots import check_plot_path, evaluation_figure, save_figure
from giwbc.apps.progress import Progress, add_progress_argument, wants_progress
from giwbc.apps.workers import map_jobs, quiet_banners
from giwbc.distributed import RayRunner, add_ray_argument, connect
from giwbc.errors import EstimatorCalibrationError
from giwbc.locomotion.push_scoring import SETTLE_AFTER_PUSH_S, fall_times_summary, judge_push
from giwbc.locomotion.tracking import per_tick_tracking
import giwbc.envs  # noqa: F401  (registers the giwbc/ ids)
from giwbc.policy import OnnxPolicy, PolicyFormatError, check_compatible
from giwbc.envs.plant_runtime import is_distribution
from giwbc.plants import resolve_plant
from giwbc.randomization.plant_distribution import PlantDistribution
from giwbc.robot import load as load_robot
from giwbc.util.shipped import shipped_policy

DEFAULT_ENV_ID = "giwbc/G1Balance-v0"
# The environment as registered (both WBC solvers give bit-reproducible answers).
DEFAULT_ENV_KWARGS: dict[str, Any] = {}
EVAL_SEED = 1000  # evaluation episodes use seeds 1000.. (training resets draw from seeds 0..n_envs-1)


@dataclass(frozen=True)
class PushProtocol:
    """One push per episode (see the module docstring)."""

    force: float = 80.0
    duration: float = 0.2
    interval: tuple[float, float] = (1.2, 1.6)
    episode_seconds: float = round(1.6 + 0.2 + SETTLE_AFTER_PUSH_S, 6)  # the latest push's end + the settle window
    upright_tilt: float = 0.35
    plant: str | None = None  # the simulated plant (giwbc.plants: a variant's name, a .toml or MJCF path); None: the robot's own model

    def __post_init__(self) -> None:
        low, high = self.interval
        if not (0 < low <= high) or self.duration <= 0 or self.force < 0:
            raise ValueError(f"bad push protocol {self}")
        if high >= self.push_horizon:
            raise ValueError(f"one push per episode: interval[1] must be < 2*interval[0] + duration = {self.push_horizon:.2f} s "
                             "(a second push could start before the latest first one)")
        if self.episode_seconds < settled_episode_seconds(self.interval, self.duration) - 1e-9:
            raise ValueError(f"success is judged {SETTLE_AFTER_PUSH_S:g} s after the push ends: episode_seconds must be >= "
                             f"interval[1] + duration + {SETTLE_AFTER_PUSH_S:g} = {settled_episode_seconds(self.interval, self.duration):.2f} s")

    @property
    def push_horizon(self) -> float:
        """s: pushes are drawn for this much of the episode, after the latest first push and before any second one."""
        return 2 * self.interval[0] + self.duration

    def env_overrides(self, base_kwargs: dict[str, Any], agent_hz: float) -> dict[str, Any]:
        """``gymnasium.make`` options: the environment's own, with this protocol's pushes and time limit."""
        sim2real = dict(base_kwargs.get("sim2real") or {})
        sim2real["pushes"] = {"interval": list(self.interval), "duration": self.duration, "force": [self.force, self.force],
                              "horizon": self.push_horizon}
        plant = {} if self.plant is None else {"plant": self.plant}
        return {**base_kwargs, **plant, "sim2real": sim2real, "max_episode_steps": math.ceil(self.episode_seconds * agent_hz - 1e-9)}  # never short of the settle window


def settled_episode_seconds(interval: tuple[float, float], duration: float) -> float:
    """The shortest episode that judges a push starting in ``interval`` for ``duration`` s:
    its latest end plus :data:`~giwbc.locomotion.push_scoring.SETTLE_AFTER_PUSH_S`."""
    return round(interval[1] + duration + SETTLE_AFTER_PUSH_S, 6)


@dataclass(frozen=True)
class EpisodeResult:
    seed: int
    survived: bool
    success: bool
    survival_time: float  # s (the episode length if it survived)
    final_tilt: float  # rad
    max_tilt: float  # rad
    push_time: float  # s, first agent step at which the push was on (nan: none)
    push_force: tuple[float, float, float]
    episode_return: float
    tracking_rms: float | None = None  # m/s, walking tasks: 1-s window averages (velocity_tracking_rms); None otherwise or when no window fits
    fall_after_push: float | None = None  # s from the push's end to the fall (terminated episodes; < 0: during the push); None: no fall
    # Walking tasks: per-tick (agent step) heading-frame errors from 1 s on (giwbc.locomotion.tracking); None otherwise.
    tracking_rms_per_tick_heading_xy: float | None = None  # m/s
    tracking_mean_abs_per_tick_heading_xy: float | None = None  # m/s
    yaw_rate_rms_per_tick: float | None = None  # rad/s
    yaw_rate_mean_abs_per_tick: float | None = None  # rad/s
    plant: str | None = None  # the plant the episode ran on, where the environment draws one (plant="random"); None otherwise
    started: bool = True  # False: the estimator in the loop did not calibrate at reset (no step ran; a failure in both arms)


TRACKING_START = 1.0  # s: walking tasks' tracking figures (windows and ticks) from here (the gait is established)


def velocity_tracking_rms(times: np.ndarray, xy: np.ndarray, yaw: np.ndarray, commands: np.ndarray,
                          window: float = 1.0, start: float = TRACKING_START) -> float:
    """RMS over consecutive ``window``-s windows from ``start`` s of ``‖v̄ − v_cmd‖`` (xy, m/s): the
    base displacement over the window in the heading frame of its start, divided by its duration
    (a window average: the gait's sway averages out), against the command held over the window
    (windows where the command changed are skipped). nan when no window fits."""
    times = np.asarray(times, dtype=float)
    errors = []
    i = int(np.searchsorted(times, start - 1e-9))
    while i < len(times):
        j = int(np.searchsorted(times, times[i] + window - 1e-9))
        if j >= len(times):
            break
        if np.array_equal(commands[i], commands[j]):
            c, s = math.cos(yaw[i]), math.sin(yaw[i])
            d = (xy[j] - xy[i]) / (times[j] - times[i])
            v = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
            errors.append(float(np.sum((v - commands[i][:2]) ** 2)))
        i = j
    return math.sqrt(float(np.mean(errors))) if errors else math.nan


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a success rate."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    center = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, center - half), min(1.0, center + half))


@dataclass(frozen=True)
class ArmResult:
    """One controller (``"wbc"`` alone or a policy) over seeded episodes."""

    name: str
    protocol: PushProtocol
    episodes: tuple[EpisodeResult, ...]

    @property
    def n(self) -> int:
        return len(self.episodes)

    @property
    def successes(self) -> int:
        return sum(e.success for e in self.episodes)

    @property
    def success_rate(self) -> float:
        return self.successes / max(1, self.n)

    @property
    def success_95ci(self) -> tuple[float, float]:
        """95 % Wilson interval of the success rate."""
        return wilson_interval(self.successes, self.n)

    @property
    def survival_rate(self) -> float:
        return sum(e.survived for e in self.episodes) / max(1, self.n)

    @property
    def mean_survival_time(self) -> float:
        return float(np.mean([e.survival_time for e in self.episodes]))

    def summary(self) -> dict[str, Any]:
        low, high = self.success_95ci
        return {
            "arm": self.name,
            "episodes": self.n,
            "success_rate": self.success_rate,
            "success_rate_95ci": [low, high],
            "survival_rate": self.survival_rate,
            "mean_survival_time_s": self.mean_survival_time,
            "mean_return": float(np.mean([e.episode_return for e in self.episodes])),
            "mean_max_tilt_rad": float(np.mean([e.max_tilt for e in self.episodes if e.started] or [math.nan])),
            "not_started": sum(not e.started for e in self.episodes),  # estimator calibration failed at reset: counted as failures
            "settle_after_push_s": SETTLE_AFTER_PUSH_S,
            **fall_times_summary([e.fall_after_push for e in self.episodes if e.fall_after_push is not None]),
        }


@dataclass(frozen=True)
class Comparison:
    wbc: ArmResult
    residual: ArmResult
    env_id: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)

    @property
    def same_pushes(self) -> bool:
        """Both arms saw the same push (direction, magnitude, time) in every episode."""
        return all(
            np.allclose(a.push_force, b.push_force) and (a.push_time == b.push_time or not (a.survived and b.survived))
            for a, b in zip(self.wbc.episodes, self.residual.episodes)
        )

    @property
    def same_plants(self) -> bool:
        """Both arms ran every episode on the same plant (always, unless a plant distribution drew differently)."""
        return all(a.plant == b.plant for a, b in zip(self.wbc.episodes, self.residual.episodes))

    @property
    def saved(self) -> int:
        """Episodes the residual policy succeeds in and the WBC alone fails (same seed, same push)."""
        return sum(b.success and not a.success for a, b in zip(self.wbc.episodes, self.residual.episodes))

    @property
    def lost(self) -> int:
        """Episodes the WBC alone succeeds in and the residual policy fails."""
        return sum(a.success and not b.success for a, b in zip(self.wbc.episodes, self.residual.episodes))

    @property
    def paired_p_value(self) -> float:
        """Exact two-sided McNemar test on the discordant pairs (``saved`` vs ``lost``): the
        probability of a split at least this uneven if neither arm were better."""
        return mcnemar_exact(self.saved, self.lost)

    def summary(self) -> dict[str, Any]:
        return {
            "env_id": self.env_id,
            "protocol": asdict(self.wbc.protocol),
            "wbc": self.wbc.summary(),
            "residual": self.residual.summary(),
            "same_pushes": self.same_pushes,
            "paired": {"saved": self.saved, "lost": self.lost, "mcnemar_exact_p": self.paired_p_value},
            **({"same_plants": self.same_plants, "per_plant": per_plant(self)} if any(e.plant for e in self.wbc.episodes) else {}),
        }


def per_plant(comparison: Comparison) -> dict[str, dict[str, Any]]:
    """Per drawn plant (plant="random"): episodes, each arm's successes with a 95 % Wilson interval,
    and the exact McNemar test of the pairs on that plant."""
    table: dict[str, dict[str, Any]] = {}
    for name in sorted({str(e.plant) for e in comparison.wbc.episodes}):
        pairs = [(a, b) for a, b in zip(comparison.wbc.episodes, comparison.residual.episodes) if str(a.plant) == name]
        n = len(pairs)
        wins = [sum(a.success for a, _ in pairs), sum(b.success for _, b in pairs)]
        saved = sum(b.success and not a.success for a, b in pairs)
        lost = sum(a.success and not b.success for a, b in pairs)
        table[name] = {"episodes": n, "wbc_successes": wins[0], "wbc_95ci": list(wilson_interval(wins[0], n)),
                       "residual_successes": wins[1], "residual_95ci": list(wilson_interval(wins[1], n)),
                       "saved": saved, "lost": lost, "mcnemar_exact_p": mcnemar_exact(saved, lost)}
    return table


def arm_per_plant(arm: ArmResult) -> dict[str, dict[str, Any]]:
    """One arm's successes per drawn plant (plant="random"), with 95 % Wilson intervals; {} on one plant."""
    table: dict[str, dict[str, Any]] = {}
    for name in sorted({str(e.plant) for e in arm.episodes if e.plant is not None}):
        episodes = [e for e in arm.episodes if e.plant == name]
        wins = sum(e.success for e in episodes)
        table[name] = {"episodes": len(episodes), "successes": wins, "success_95ci": list(wilson_interval(wins, len(episodes)))}
    return table


def format_per_plant(comparison: Comparison) -> str:
    """The per-plant table of a paired comparison on drawn plants, one line per plant ('' without plants)."""
    if not any(e.plant for e in comparison.wbc.episodes):
        return ""
    lines = [f"per drawn plant at {comparison.wbc.protocol.force:g} N (same plant in both arms: {comparison.same_plants}):"]
    for name, row in per_plant(comparison).items():
        lines.append(f"  {name:<20} n={row['episodes']:<4} walker alone {row['wbc_successes']}/{row['episodes']} "
                     f"[{row['wbc_95ci'][0]:.2f}, {row['wbc_95ci'][1]:.2f}], residual {row['residual_successes']}/{row['episodes']} "
                     f"[{row['residual_95ci'][0]:.2f}, {row['residual_95ci'][1]:.2f}], saves {row['saved']}, loses {row['lost']} "
                     f"(McNemar p = {row['mcnemar_exact_p']:.3g})")
    return "\n".join(lines)


def _episodes(n: int) -> str:
    return f"{n} episode" + ("" if n == 1 else "s")


def mcnemar_exact(b: int, c: int) -> float:
    """Two-sided exact McNemar p-value for ``b`` and ``c`` discordant pairs (binomial, p = 1/2)."""
    n = b + c
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, k) for k in range(min(b, c) + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)


# --- running episodes ---------------------------------------------------------------------------
def _tilt(env: Any) -> float:
    return float(env.unwrapped.task.tilt())


def _run_chunk(job: tuple[str | None, str, dict[str, Any], PushProtocol, list[int]],
               tick: Callable[[int], None] | None = None) -> list[EpisodeResult]:
    """Episodes ``seeds`` in one process (one environment, reset per seed); ``tick(1)`` after each."""
    policy_path, env_id, env_kwargs, protocol, seeds = job
    import gymnasium


    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    policy = None
    if policy_path is not None:
        policy = OnnxPolicy(policy_path)
    with quiet_banners():  # PyBullet prints its build time at connect
        probe = gymnasium.make(env_id, **env_kwargs)
        agent_hz = float(probe.unwrapped.describe()["rates"]["agent_hz"])
        probe.close()
        env = gymnasium.make(env_id, **protocol.env_overrides(env_kwargs, agent_hz))
    if policy is not None:
        check_compatible(policy.metadata, env.unwrapped.describe())
    zero = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    results = []
    try:
        for seed in seeds:
            try:
                observation, reset_info = env.reset(seed=seed)
            except EstimatorCalibrationError:  # at reset, before any action: the same in both arms, counted, never a crash
                results.append(EpisodeResult(seed=seed, survived=False, success=False, survival_time=0.0, final_tilt=math.nan,
                                             max_tilt=math.nan, push_time=math.nan, push_force=(0.0, 0.0, 0.0), episode_return=0.0,
                                             plant=getattr(env.unwrapped, "plant", None), started=False))
                if tick is not None:
                    tick(1)
                continue
            plant = reset_info.get("plant")
            total, max_tilt, push_time, push_force = 0.0, 0.0, math.nan, (0.0, 0.0, 0.0)
            terminated = truncated = False
            info: dict[str, Any] = {}
            # Walking tasks: time, base xy, yaw, command, base xy velocity (world), yaw rate, at every agent step.
            trace: list[tuple[float, np.ndarray, float, np.ndarray, np.ndarray, float]] = []
            while not (terminated or truncated):
                action = policy(observation) if policy is not None else zero
                observation, reward, terminated, truncated, info = env.step(action)
                total += float(reward)
                max_tilt = max(max_tilt, _tilt(env))
                if "command" in info:
                    trace.append((float(info["time"]), info["base_xy"], float(info["base_yaw"]), info["command"],
                                  info["base_velocity_xy"], float(info["base_yaw_rate"])))
                if math.isnan(push_time) and info.get("pushes", 0) > 0:
                    push_time = float(info["time"])
                    push_force = tuple(float(f) for f in info["push_force"])
            final_tilt = _tilt(env)
            survived = not terminated
            end_time = float(info.get("time", 0.0))
            # push_time ends the agent step the push started in: the push ended at most at this (within one agent step).
            push_end = min(push_time, protocol.interval[1]) + protocol.duration if math.isfinite(push_time) else math.nan
            outcome = judge_push(fell=terminated, fall_time=end_time, end_time=end_time, push_end=push_end,
                                 final_tilt=final_tilt, upright_tilt=protocol.upright_tilt)
            tracking: dict[str, Any] = {}
            if trace:
                times, xy, yaw, commands, velocity, yaw_rate = (np.array(column) for column in zip(*trace))
                rms = velocity_tracking_rms(times, xy, yaw, commands)
                tracking["tracking_rms"] = rms if math.isfinite(rms) else None
                scored = times >= TRACKING_START - 1e-9
                if scored.any():
                    per_tick = per_tick_tracking(velocity[scored], yaw[scored], yaw_rate[scored], commands[scored]).summary()
                    tracking |= {key: value for key, value in per_tick.items() if key != "ticks"}
            results.append(EpisodeResult(
                seed=seed, survived=survived, success=outcome.success,
                survival_time=end_time, final_tilt=final_tilt, max_tilt=max_tilt,
                push_time=push_time, push_force=push_force, episode_return=total, fall_after_push=outcome.fall_after_push,
                plant=None if plant is None else str(plant), **tracking,
            ))
            if tick is not None:
                tick(1)
    finally:
        env.close()
    return results


def run_episodes(
    policy_path: str | os.PathLike[str] | None,
    *,
    env_id: str = DEFAULT_ENV_ID,
    env_kwargs: dict[str, Any] | None = None,
    protocol: PushProtocol = PushProtocol(),
    episodes: int = 50,
    seed: int = 0,
    workers: int = 2,
    runner: RayRunner | None = None,
    progress: Callable[[int], None] | None = None,
) -> ArmResult:
    """``episodes`` seeded episodes (seeds ``seed .. seed+episodes-1``) of a policy, or of the zero residual if ``None``.

    ``workers``: processes of this machine, or with ``runner`` the number of Ray tasks the episodes are split into.
    ``progress(n)``: told of every ``n`` episodes finished, as they finish (not with ``runner``).
    """
    if runner is not None:
        return run_arms([{"policy_path": policy_path, "env_id": env_id, "env_kwargs": env_kwargs, "protocol": protocol,
                          "episodes": episodes, "seed": seed, "workers": workers}], runner)[0]
    jobs = _episode_jobs(policy_path, env_id, env_kwargs, protocol, episodes, seed, workers)
    workers = 0 if len(jobs) == 1 else len(jobs)
    results = [r for chunk in map_jobs(_run_chunk, jobs, workers, progress) for r in chunk]
    return _arm_result(policy_path, protocol, results)


_Job = tuple[str | None, str, dict[str, Any], PushProtocol, list[int]]


def _episode_jobs(policy_path: str | os.PathLike[str] | None, env_id: str, env_kwargs: dict[str, Any] | None,
                  protocol: PushProtocol, episodes: int, seed: int, workers: int) -> list[_Job]:
    """The seeds ``seed .. seed+episodes-1`` dealt round-robin into ``workers`` jobs for :func:`_run_chunk`."""
    env_kwargs = dict(DEFAULT_ENV_KWARGS if env_kwargs is None else env_kwargs)
    seeds = list(range(seed, seed + episodes))
    workers = max(1, min(workers, episodes))
    chunks = [seeds[i::workers] for i in range(workers)]
    path = None if policy_path is None else str(policy_path)
    return [(path, env_id, env_kwargs, protocol, chunk) for chunk in chunks if chunk]


def _arm_result(policy_path: str | os.PathLike[str] | None, protocol: PushProtocol, results: list[EpisodeResult]) -> ArmResult:
    name = "wbc" if policy_path is None else os.path.basename(str(policy_path))
    return ArmResult(name, protocol, tuple(sorted(results, key=lambda r: r.seed)))


def _describe_job(job: _Job) -> str:
    path, env_id, _, protocol, seeds = job
    return f"{path or 'wbc'} on {env_id} at {protocol.force:g} N, seeds {seeds}"


def run_arms(arms: Sequence[dict[str, Any]], runner: RayRunner) -> list[ArmResult]:
    """Several arms (each :func:`run_episodes`' keyword arguments) at once as Ray tasks: a whole sweep
    keeps a cluster busy instead of waiting for each arm's slowest task. Same results as one by one."""
    jobs = [_episode_jobs(arm.get("policy_path"), arm.get("env_id", DEFAULT_ENV_ID), arm.get("env_kwargs"),
                          arm.get("protocol", PushProtocol()), arm.get("episodes", 50), arm.get("seed", 0), arm.get("workers", 2))
            for arm in arms]
    flat = runner.map(_run_chunk, [job for arm_jobs in jobs for job in arm_jobs], describe=_describe_job)
    results, start = [], 0
    for arm, arm_jobs in zip(arms, jobs, strict=True):
        chunks, start = flat[start : start + len(arm_jobs)], start + len(arm_jobs)
        results.append(_arm_result(arm.get("policy_path"), arm.get("protocol", PushProtocol()), [r for c in chunks for r in c]))
    return results


def policy_env(policy_path: str | os.PathLike[str]) -> tuple[str, dict[str, Any]]:
    """The environment id and options a policy file was trained on (from its metadata)."""
    metadata = OnnxPolicy(policy_path).metadata
    env_id = metadata["env_id"]
    return (env_id if ":" in env_id else f"giwbc.envs:{env_id}"), dict(metadata["env_kwargs"])


def _strip_time_limit(env_kwargs: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in env_kwargs.items() if k != "max_episode_steps"}


def compare(
    policy_path: str | os.PathLike[str],
    *,
    protocol: PushProtocol = PushProtocol(),
    episodes: int = 50,
    seed: int = 0,
    workers: int = 2,
    runner: RayRunner | None = None,
    progress: Callable[[int], None] | None = None,
) -> Comparison:
    """The policy against the zero residual on the policy's own environment, same seeds, same pushes
    (with ``runner``, both arms at once as Ray tasks)."""
    if runner is not None:
        return compare_forces(policy_path, [protocol], episodes=episodes, seed=seed, workers=workers, runner=runner)[0]
    env_id, env_kwargs = policy_env(policy_path)
    env_kwargs = _strip_time_limit(env_kwargs)
    common = {"env_id": env_id, "env_kwargs": env_kwargs, "protocol": protocol, "episodes": episodes, "seed": seed,
              "workers": workers, "progress": progress}
    wbc = run_episodes(None, **common)
    residual = run_episodes(policy_path, **common)
    return Comparison(wbc, residual, env_id, env_kwargs)


def compare_forces(
    policy_path: str | os.PathLike[str],
    protocols: Sequence[PushProtocol],
    *,
    episodes: int = 50,
    seed: int = 0,
    workers: int = 2,
    runner: RayRunner,
) -> list[Comparison]:
    """:func:`compare` for each protocol (e.g. each push force), every arm's episodes at once as Ray tasks."""
    env_id, env_kwargs = policy_env(policy_path)
    env_kwargs = _strip_time_limit(env_kwargs)
    common = {"env_id": env_id, "env_kwargs": env_kwargs, "episodes": episodes, "seed": seed, "workers": workers}
    arms = run_arms([{"policy_path": path, "protocol": protocol, **common} for protocol in protocols for path in (None, policy_path)],
                    runner)
    return [Comparison(arms[2 * i], arms[2 * i + 1], env_id, env_kwargs) for i in range(len(protocols))]


def sweep(
    forces: Sequence[float],
    *,
    env_id: str = DEFAULT_ENV_ID,
    env_kwargs: dict[str, Any] | None = None,
    protocol: PushProtocol = PushProtocol(),
    episodes: int = 50,
    seed: int = 0,
    workers: int = 2,
    policy_path: str | os.PathLike[str] | None = None,
    runner: RayRunner | None = None,
    progress: Callable[[int], None] | None = None,
) -> list[ArmResult]:
    """Success rate against push magnitude (the zero residual unless ``policy_path``): to pick a force that discriminates.

    With ``runner``, every force's episodes at once as Ray tasks."""
    if policy_path is not None:
        env_id, env_kwargs = policy_env(policy_path)
        env_kwargs = _strip_time_limit(env_kwargs)
    from dataclasses import replace

    if runner is not None:
        return run_arms([{"policy_path": policy_path, "env_id": env_id, "env_kwargs": env_kwargs, "episodes": episodes,
                          "seed": seed, "workers": workers, "protocol": replace(protocol, force=float(force))}
                         for force in forces], runner)

    return [
        run_episodes(policy_path, env_id=env_id, env_kwargs=env_kwargs, protocol=replace(protocol, force=float(force)),
                     episodes=episodes, seed=seed, workers=workers, progress=progress)
        for force in forces
    ]


def format_table(rows: Sequence[ArmResult]) -> str:
    lines = [f"{'arm':<28}{'push N':>8}{'episodes':>10}{'success':>10}{'95% CI':>16}{'survived':>10}{'mean surv. s':>14}"]
    for arm in rows:
        low, high = wilson_interval(arm.successes, arm.n)
        lines.append(
            f"{arm.name:<28}{arm.protocol.force:>8.0f}{arm.n:>10}{arm.success_rate:>10.0%}{f'[{low:.2f}, {high:.2f}]':>16}"
            f"{arm.survival_rate:>10.0%}{arm.mean_survival_time:>14.2f}"
        )
    return "\n".join(lines)


def success_rule(protocol: PushProtocol) -> str:
    """The success criterion in words, for the printed reports."""
    return (f"success = no fall and tilt < {protocol.upright_tilt} rad at the end, the end at least {SETTLE_AFTER_PUSH_S:g} s "
            "after the push ends")


def format_falls(rows: Sequence[ArmResult]) -> str:
    """When each arm's robots fell, in s after the push ended (negative: during the push)."""
    lines = []
    for arm in rows:
        falls = sorted(e.fall_after_push for e in arm.episodes if e.fall_after_push is not None)
        if falls:
            lines.append(f"falls of {arm.name} at {arm.protocol.force:g} N, s after the push ended: "
                         + ", ".join(f"{f:.2f}" for f in falls))
    return "\n".join(lines) if lines else "no fall after a push"


# --- command line ------------------------------------------------------------------------------
MAX_EPISODES = 10_000
MAX_FORCE = 1000.0  # N
MAX_EPISODE_SECONDS = 600.0  # simulated
MAX_WORKERS = 256


def add_evaluate_command(commands: Any) -> None:
    """Add ``giwbc evaluate`` to an argparse subparsers object."""
    parser = add_command(commands, "evaluate", "seeded push-recovery evaluation: a residual policy vs the WBC alone")
    parser.add_argument("--policy", type=policy_file(), default=None,
                        help="policy .onnx trained on the protocol's environment, or a shipped policy's name "
                             "(default: only the WBC alone, on --env/--env-kwargs)")
    parser.add_argument("--episodes", type=integer(1, MAX_EPISODES), default=50, help=f"seeded episodes per arm and force, in [1, {MAX_EPISODES}]")
    parser.add_argument("--seed", type=seed(), default=EVAL_SEED,
                        help="episode seeds are seed .. seed+episodes-1, the same in both arms (default: held out from training)")
    parser.add_argument("--workers", type=integer(1, MAX_WORKERS), default=None,
                        help="worker processes (default 2), or with --ray Ray tasks per arm (default: the cluster's CPUs)")
    add_ray_argument(parser)
    parser.add_argument("--force", type=number(0.0, MAX_FORCE, unit="N"), nargs="+", default=[PushProtocol.force],
                        help=f"push magnitude(s), N, each in [0, {MAX_FORCE:g}]")
    parser.add_argument("--duration", type=seconds(1.0), default=PushProtocol.duration, help="push duration, s, in (0, 1]")
    parser.add_argument("--interval", type=seconds(MAX_EPISODE_SECONDS, allow_zero=True), nargs=2, default=None, metavar=("MIN", "MAX"),
                        help=f"push start drawn uniformly in [MIN, MAX] simulated s; the push must end {SETTLE_AFTER_PUSH_S:g} s before "
                             f"the episode does (default stand {list(PushProtocol.interval)})")
    parser.add_argument("--episode-seconds", type=seconds(MAX_EPISODE_SECONDS), default=None,
                        help=f"simulated seconds per episode, at least the latest push's end + {SETTLE_AFTER_PUSH_S:g} s (success is "
                             f"judged then; default: exactly that, stand {PushProtocol.episode_seconds:g})")
    parser.add_argument("--upright-tilt", type=number(0.0, math.pi / 2, unit="rad", low_open=True), default=PushProtocol.upright_tilt,
                        help="success: final base tilt below this, rad")
    parser.add_argument("--env", default=None, choices=(DEFAULT_ENV_ID, "giwbc/G1Walk-v0"),
                        help=f"environment of the WBC-alone arm when no --policy is given (default {DEFAULT_ENV_ID}, walk: giwbc/G1Walk-v0)")
    parser.add_argument("--env-kwargs", default=json.dumps(DEFAULT_ENV_KWARGS), help="JSON object of --env's gymnasium.make options")
    parser.add_argument("--plant", default=None, help="the simulated plant of every arm: a variant of robots/<robot>/plants (e.g. "
                        "point_feet), a variant .toml or a vendor's MJCF file (.xml) of the robot, or 'random' (or a plant-distribution .toml): "
                        "a plant drawn per episode from the seed, the same in both arms, figures also per drawn plant "
                        "(default: the robot's own model)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--plot", default=None, metavar="FILE",
                        help="also draw success rate against push impulse per arm, and the paired counts (.png, .svg, .pdf)")
    add_progress_argument(parser)
    parser.set_defaults(run=run_evaluate_command)


def check_plant(args: Any) -> str | None:
    """``--plant``, refused here in one line (PlantMismatchError, RandomizationError for a distribution)
    when the robot cannot run on it."""
    plant = getattr(args, "plant", None)
    if plant is not None:
        robot = load_robot(json.loads(getattr(args, "env_kwargs", "{}") or "{}").get("robot", "g1"))
        if is_distribution(plant):
            PlantDistribution.load(plant, robot)
        else:
            resolve_plant(robot, plant)
    return plant


def run_evaluate_command(args: Any) -> int:
    import sys


    connection = None
    bar = Progress(0, "evaluate", enabled=False)
    try:
        if args.plot:
            check_plot_path(args.plot)  # before the run, not after it
        interval = tuple(args.interval or PushProtocol.interval)
        protocol = PushProtocol(force=args.force[0], duration=args.duration, interval=interval,  # type: ignore[arg-type]
                                episode_seconds=args.episode_seconds or settled_episode_seconds(interval, args.duration),  # type: ignore[arg-type]
                                upright_tilt=args.upright_tilt, plant=check_plant(args))
        connection = connect(args.ray) if getattr(args, "ray", None) else None
        runner = RayRunner(connection) if connection is not None else None
        workers = args.workers or (runner.cpus if runner is not None else 2)
        common: dict[str, Any] = {"episodes": args.episodes, "seed": args.seed, "workers": workers, "runner": runner}
        arms = len(args.force) * (1 if args.policy is None else 2)
        bar = Progress(args.episodes * arms, "evaluate", enabled=wants_progress(args) and runner is None)  # Ray: no live count
        if bar.enabled:
            common["progress"] = bar
        rows: list[ArmResult] = []
        comparisons: list[Comparison] = []
        summary: dict[str, Any]
        if args.policy is None:
            rows = sweep(args.force, env_id=args.env or DEFAULT_ENV_ID, env_kwargs=json.loads(args.env_kwargs), protocol=protocol, **common)
            summary = {"env_id": args.env or DEFAULT_ENV_ID, "arms": [r.summary() | {"force": r.protocol.force}
                                                                         | ({"per_plant": arm_per_plant(r)} if arm_per_plant(r) else {}) for r in rows]}
        else:
            from dataclasses import replace

            if runner is not None:  # every force's two arms at once
                comparisons = compare_forces(args.policy, [replace(protocol, force=force) for force in args.force], **common)
            else:
                comparisons = [compare(args.policy, protocol=replace(protocol, force=force), **common) for force in args.force]
            for comparison in comparisons:
                rows += [comparison.wbc, comparison.residual]
            summary = {"comparisons": [c.summary() for c in comparisons]}
    except (PolicyFormatError, FileNotFoundError, ValueError) as error:
        print(f"giwbc evaluate: error: {error}", file=sys.stderr)
        return 2
    finally:
        bar.close()
        if connection is not None:
            connection.close()
    if args.plot:
        save_figure(evaluation_figure(rows, comparisons), args.plot)
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"one push per episode: {protocol.duration} s, random horizontal direction, start uniform in "
              f"{list(protocol.interval)} s; episodes of {protocol.episode_seconds:g} s; {success_rule(protocol)}; "
              f"seeds {args.seed}..{args.seed + args.episodes - 1}")
        print(format_table(rows))
        print(format_falls(rows))
        if args.policy is not None:
            print("same pushes in both arms: " + ", ".join(str(c.same_pushes) for c in comparisons))
            for c in comparisons:
                print(f"paired at {c.wbc.protocol.force:g} N: the residual saves {_episodes(c.saved)} the WBC alone loses, "
                      f"loses {c.lost} the WBC alone saves (exact McNemar p = {c.paired_p_value:.3g})")
                if format_per_plant(c):
                    print(format_per_plant(c))
    return 0


# --- any policy, any env: return and a per-step predicate (e.g. CartPole swing-up) --------------------
@dataclass(frozen=True)
class UprightResult:
    """Mean return and fraction of agent steps with the pole within ``upright_angle`` of vertical."""

    arm: str
    returns: tuple[float, ...]
    upright_fractions: tuple[float, ...]

    def summary(self) -> dict[str, Any]:
        return {"arm": self.arm, "episodes": len(self.returns), "mean_return": float(np.mean(self.returns)),
                "min_return": float(np.min(self.returns)), "mean_upright_fraction": float(np.mean(self.upright_fractions))}


def evaluate_swing_up(
    arm: str,
    *,
    env_id: str = "giwbc/CartPoleSwingUp-v0",
    env_kwargs: dict[str, Any] | None = None,
    episodes: int = 20,
    seed: int = 0,
    upright_angle: float = 0.2,
) -> UprightResult:
    """``arm``: a policy file, ``"zero"`` (no force) or ``"random"`` (uniform actions, seeded per episode)."""
    import gymnasium


    policy = None
    if arm not in ("zero", "random"):
        policy = OnnxPolicy(arm)
        env = policy.make_env(**(env_kwargs or {}))
    else:
        env = gymnasium.make(env_id, **(env_kwargs or {}))
    returns, fractions = [], []
    try:
        for episode in range(episodes):
            observation, _ = env.reset(seed=seed + episode)
            env.action_space.seed(seed + episode)
            total, upright, steps, done = 0.0, 0, 0, False
            while not done:
                if policy is not None:
                    action = policy(observation)
                elif arm == "zero":
                    action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
                else:
                    action = env.action_space.sample()
                observation, reward, terminated, truncated, _ = env.step(action)
                theta = env.unwrapped.task.state()[2]
                upright += abs(math.remainder(theta, 2 * math.pi)) < upright_angle
                total += float(reward)
                steps += 1
                done = terminated or truncated
            returns.append(total)
            fractions.append(upright / steps)
    finally:
        env.close()
    return UprightResult(os.path.basename(arm), tuple(returns), tuple(fractions))


SHIPPED_POLICY = str(shipped_policy("g1_balance_residual") or "policies/g1_balance_residual.onnx")  # the wheel's or the checkout's


def demo_residual(policy_path: str | os.PathLike[str] = SHIPPED_POLICY, *, episodes: int = 12, force: float = 80.0,
                  seed: int = EVAL_SEED, workers: int = 2) -> Comparison | None:
    """For ``make demo``: the shipped residual policy vs the WBC alone, a few seeded pushes each (~10-20 s)."""
    from pathlib import Path

    path = Path(policy_path)
    if not path.is_file():
        print(f"  no residual policy at {path}: skipped (train one with `giwbc train`, see policies/README.md)")
        return None
    protocol = PushProtocol(force=force)
    comparison = compare(path, protocol=protocol, episodes=episodes, seed=seed, workers=workers)
    print(f"residual RL ({path.name}) vs the WBC alone: one {force:.0f} N push for {protocol.duration} s in a random horizontal "
          f"direction per {protocol.episode_seconds} s episode, seeds {seed}..{seed + episodes - 1}, same pushes in both arms:")
    for line in format_table([comparison.wbc, comparison.residual]).splitlines():
        print("  " + line)
    print(f"  paired: the residual saves {_episodes(comparison.saved)} the WBC alone loses and loses {comparison.lost} it saves "
          "(the 100-episode figures: policies/README.md)")
    return comparison
