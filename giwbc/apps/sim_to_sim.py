"""Sim-to-sim evaluation: the same controllers on MuJoCo nominal, MuJoCo randomized and PyBullet.

The first check of a policy before hardware, as Gym-Ignition suggests: a controller that only
works on the engine and parameters it was tuned on will not survive the real robot. Each
controller -- the WBC alone (zero residual) and, when given, a residual ONNX policy trained on
``G1Balance-v0`` -- runs the same seeded episodes under the same pushes on three conditions:

* ``mujoco_nominal``: the description's parameters;
* ``mujoco_randomized``: the robot's shipped domain randomization (``robots/g1/randomization.toml``);
* ``pybullet``: the other engine, nominal parameters.

Pushes start during the first ``seconds`` of an episode; the episode then runs on, unpushed,
until :data:`~giwbc.locomotion.push_scoring.SETTLE_AFTER_PUSH_S` (3 s) after the last push can
have ended (``seconds + duration + 3`` s in all), so that a slow topple after a late push is seen.
Success: the episode ran its full length without terminating (fall or excessive tilt); each fall
is reported with its time after the last push ended. Episodes
are grouped in fixed chunks of seeds, each chunk run by one worker process on one environment, so
the result does not depend on the number of workers, nor on whether the chunks ran as Ray tasks
on a cluster (``--ray``, see :mod:`giwbc.distributed`). Prints a markdown table (one JSON object with ``--json``)::

    python examples/sim_to_sim.py --episodes 50 --seconds 10 --push-force 90 --workers 2
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from contextlib import nullcontext
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from giwbc.apps.arguments import HelpFormatter, add_command, integer, number, policy_file, seconds, seed
from giwbc.apps.evaluation import wilson_interval
from giwbc.apps.plots import check_plot_path, save_figure, sim_to_sim_figure
from giwbc.apps.progress import Progress, add_progress_argument, wants_progress
from giwbc.apps.workers import map_jobs, quiet_banners
from giwbc.distributed import RayRunner, add_ray_argument, connect
from giwbc.envs import RUNTIME_OPTIONS
from giwbc.errors import ConfigError, PolicyFormatError
from giwbc.locomotion.push_scoring import SETTLE_AFTER_PUSH_S, fall_times_summary, judge_push
from giwbc.policy import OnnxPolicy, check_compatible
from giwbc.util.shipped import shipped_policy
import giwbc.envs  # noqa: F401  (registers the giwbc/ ids)

ENV_ID = "giwbc/G1Balance-v0"
DEFAULT_POLICY_NAME = "g1_balance_residual"
DEFAULT_POLICY = shipped_policy(DEFAULT_POLICY_NAME) or Path(f"policies/{DEFAULT_POLICY_NAME}.onnx")  # installed: the wheel's copy
CONDITIONS: dict[str, dict[str, Any]] = {
    "mujoco_nominal": {"engine": "mujoco"},
    "mujoco_randomized": {"engine": "mujoco", "randomization": "default"},
    "pybullet": {"engine": "pybullet"},
}
CONTROLLERS = ("wbc_only", "residual_policy")
CHUNK = 5  # episodes per job: one environment build per job
MAX_EPISODES = 10_000
MAX_SECONDS = 600.0  # simulated seconds per episode
MAX_FORCE = 1000.0  # N
MAX_WORKERS = 256


@dataclass(frozen=True)
class PushSetting:
    """The fixed pushes of every condition: a magnitude, a duration and a random wait between pushes."""

    force: float = 90.0  # where the WBC alone starts to fail on nominal MuJoCo (~70-80 % success at 10 s)
    duration: float = 0.1
    interval: tuple[float, float] = (1.0, 2.0)

    def sim2real(self, horizon: float) -> dict[str, Any]:
        """The runtime's pushes, starting only within the first ``horizon`` s of an episode."""
        return {"pushes": {"force": [self.force, self.force], "duration": self.duration, "interval": list(self.interval),
                           "horizon": horizon}}

    def episode_seconds(self, seconds: float) -> float:
        """An episode pushed for ``seconds``: on until the settle window after the latest push's end."""
        return seconds + self.duration + SETTLE_AFTER_PUSH_S


@dataclass(frozen=True)
class Job:
    """A chunk of seeded episodes of one controller on one condition."""

    controller: str
    condition: str
    seeds: tuple[int, ...]
    seconds: float
    pushes: PushSetting
    policy: str | None
    env_kwargs: dict[str, Any] = field(default_factory=dict)


@dataclass
class Cell:
    """The results of one controller on one condition."""

    episodes: int = 0
    successes: int = 0
    simulated_s: float = 0.0
    wall_s: float = 0.0
    failed_seeds: list[int] = field(default_factory=list)
    fall_after_push_s: list[float] = field(default_factory=list)  # s from the last push's end to each fall

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes if self.episodes else float("nan")

    @property
    def success_95ci(self) -> tuple[float, float]:
        """95 % Wilson interval of the success rate."""
        return wilson_interval(self.successes, self.episodes)

    def summary(self) -> dict[str, Any]:
        return {
            "episodes": self.episodes,
            "successes": self.successes,
            "success_rate": self.success_rate,
            "mean_survival_s": self.simulated_s / self.episodes if self.episodes else None,
            "wall_s_per_episode": self.wall_s / self.episodes if self.episodes else None,
            "failed_seeds": sorted(self.failed_seeds),
            **fall_times_summary(self.fall_after_push_s),
        }


def _task_kwargs(policy: Any) -> dict[str, Any]:
    """The task options the policy was trained with (layout, scales, controller), runtime options dropped."""
    if policy is None:
        return {}
    kwargs = dict(policy.metadata.get("env_kwargs") or {})
    return {key: value for key, value in kwargs.items() if key not in RUNTIME_OPTIONS and key not in ("robot", "agent_rate")}


def run_job(job: Job, tick: Callable[[int], None] | None = None) -> tuple[Job, list[tuple[int, bool, float, float | None]], float]:
    """Run one chunk: ``[(seed, success, simulated seconds, fall after the last push or None)]`` and the wall time of
    its episodes; ``tick(1)`` after each."""
    import gymnasium

    policy = OnnxPolicy(job.policy) if job.controller == "residual_policy" else None
    task_policy = OnnxPolicy(job.policy) if job.policy is not None else None
    kwargs = {**_task_kwargs(task_policy), **CONDITIONS[job.condition], "sim2real": job.pushes.sim2real(job.seconds), **job.env_kwargs}
    with quiet_banners():  # PyBullet prints its build time at connect
        env = gymnasium.make(ENV_ID, **kwargs).unwrapped
    try:
        if policy is not None:
            check_compatible(policy.metadata, env.describe())
        zero = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
        steps = math.ceil(job.pushes.episode_seconds(job.seconds) * env.rates.agent - 1e-9)  # never short of the settle window
        results = []
        started = time.perf_counter()
        for seed in job.seeds:
            observation, _ = env.reset(seed=seed)
            terminated = False
            pushes, push_end = 0, math.nan
            for _ in range(steps):
                action = zero if policy is None else policy(observation)
                observation, _, terminated, _, info = env.step(action)
                if info.get("pushes", 0) > pushes:  # a push started within this agent step: it ends at most duration later
                    pushes, push_end = info["pushes"], min(env.time, job.seconds) + job.pushes.duration
                if terminated:
                    break
            outcome = judge_push(fell=terminated, fall_time=env.time, end_time=env.time, push_end=push_end)
            results.append((seed, outcome.success, env.time, outcome.fall_after_push))
            if tick is not None:
                tick(1)
        return job, results, time.perf_counter() - started
    finally:
        env.close()


def evaluate(
    *,
    policy: str | os.PathLike[str] | None = None,
    episodes: int = 50,
    seconds: float = 10.0,
    pushes: PushSetting = PushSetting(),
    workers: int = 2,
    seed: int = 0,
    conditions: Sequence[str] = tuple(CONDITIONS),
    env_kwargs: dict[str, Any] | None = None,
    runner: RayRunner | None = None,
    progress: Callable[[int], None] | None = None,
) -> dict[str, dict[str, Cell]]:
    """Success of each controller on each condition over ``episodes`` seeded episodes (``seed``, ``seed + 1``, ...).

    ``policy``: a residual ONNX policy for ``G1Balance-v0``, or ``None`` (WBC only). ``workers``:
    processes (0: run in this process). ``env_kwargs``: extra ``gymnasium.make`` options for every
    environment (e.g. ``wbc_options``). ``runner``: run the chunks as Ray tasks instead (``workers`` unused).
    ``progress(n)``: told of every ``n`` episodes finished, as they finish (not with ``runner``).
    """
    if episodes < 1 or not seconds > 0:
        raise ValueError(f"episodes must be >= 1 and seconds > 0, got {episodes}, {seconds}")
    unknown = set(conditions) - set(CONDITIONS)
    if unknown:
        raise ValueError(f"unknown conditions {sorted(unknown)}; known: {list(CONDITIONS)}")
    policy_path = str(policy) if policy is not None else None
    controllers = CONTROLLERS if policy_path is not None else CONTROLLERS[:1]
    seeds = list(range(seed, seed + episodes))
    chunks = [tuple(seeds[i : i + CHUNK]) for i in range(0, len(seeds), CHUNK)]
    jobs = [Job(controller, condition, chunk, seconds, pushes, policy_path, dict(env_kwargs or {}))
            for condition in conditions for controller in controllers for chunk in chunks]
    cells = {controller: {condition: Cell() for condition in conditions} for controller in controllers}
    if runner is not None:
        outcomes = runner.map(run_job, jobs, describe=lambda job: f"{job.controller} on {job.condition}, seeds {list(job.seeds)}")
    else:
        outcomes = map_jobs(run_job, jobs, workers, progress)
    for job, results, wall in outcomes:
        cell = cells[job.controller][job.condition]
        cell.wall_s += wall
        for episode_seed, success, survived, fall_after_push in results:
            cell.episodes += 1
            cell.successes += success
            cell.simulated_s += survived
            if not success:
                cell.failed_seeds.append(episode_seed)
            if fall_after_push is not None:
                cell.fall_after_push_s.append(fall_after_push)
    return cells


def markdown_table(cells: dict[str, dict[str, Cell]], policy_missing: bool) -> str:
    """Rows: controllers; columns: conditions; entries: successes / episodes (rate)."""
    conditions = list(next(iter(cells.values())))
    lines = ["| controller | " + " | ".join(conditions) + " |", "|---|" + "---|" * len(conditions)]
    for controller in CONTROLLERS:
        if controller in cells:
            row = [f"{c.successes}/{c.episodes} ({100 * c.success_rate:.0f} %)" for c in cells[controller].values()]
        elif policy_missing:
            row = ["missing"] * len(conditions)
        else:
            continue
        lines.append(f"| {controller} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def add_sim_to_sim_command(commands: Any) -> None:
    """Add ``giwbc sim-to-sim`` to an argparse subparsers object."""
    parser = add_command(commands, "sim-to-sim", "WBC and residual policy on MuJoCo nominal, randomized and PyBullet")
    add_arguments(parser)
    parser.set_defaults(run=run_sim_to_sim_command)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--policy", type=policy_file(), default=None,
                        help=f"residual ONNX policy trained on {ENV_ID}, a file or a shipped policy's name "
                             f"(default: the shipped {DEFAULT_POLICY_NAME} if present, else the WBC alone)")
    parser.add_argument("--no-policy", action="store_true", help="evaluate the WBC alone (no policy row)")
    parser.add_argument("--episodes", type=integer(1, MAX_EPISODES), default=50,
                        help=f"seeded episodes per controller and condition, in [1, {MAX_EPISODES}]")
    parser.add_argument("--seconds", type=seconds(MAX_SECONDS), default=10.0,
                        help=f"simulated seconds per episode, in (0, {MAX_SECONDS:g}]")
    parser.add_argument("--push-force", type=number(0.0, MAX_FORCE, unit="N"), default=PushSetting.force,
                        help=f"push magnitude, N, in [0, {MAX_FORCE:g}]")
    parser.add_argument("--push-duration", type=seconds(1.0), default=PushSetting.duration, help="push duration, s, in (0, 1]")
    parser.add_argument("--push-interval", type=seconds(MAX_SECONDS), nargs=2, default=list(PushSetting.interval), metavar=("MIN", "MAX"),
                        help="simulated seconds between pushes, drawn uniformly in [MIN, MAX], 0 < MIN <= MAX")
    parser.add_argument("--workers", type=integer(0, MAX_WORKERS), default=2, help="worker processes (0: in this process)")
    parser.add_argument("--seed", type=seed(), default=0, help="first episode seed (the others: seed + 1, ...)")
    parser.add_argument("--conditions", nargs="+", default=list(CONDITIONS), choices=list(CONDITIONS), metavar="CONDITION",
                        help=f"conditions to run, among {', '.join(CONDITIONS)}")
    parser.add_argument("--plot", default=None, metavar="FILE", help="also draw the table as grouped bars (.png, .svg, .pdf)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    add_ray_argument(parser)
    add_progress_argument(parser)


def check_policy(path: str) -> None:
    """ConfigError unless ``path`` is a policy trained on this evaluation's environment (PolicyFormatError if unreadable)."""
    env_id = OnnxPolicy(path).env_id
    if env_id != ENV_ID:
        raise ConfigError(f"{path} is a policy for {env_id}: sim-to-sim evaluates residual policies for {ENV_ID} "
                          "(for a walking policy use `giwbc evaluate --protocol walk`)")


def run_sim_to_sim_command(args: argparse.Namespace) -> int:
    policy = None if args.no_policy else args.policy
    if policy is None and not args.no_policy:
        if DEFAULT_POLICY.is_file():
            policy = str(DEFAULT_POLICY)
        else:
            print(f"no residual policy ({DEFAULT_POLICY} not found): evaluating the WBC alone; the policy row is missing",
                  file=sys.stderr)
    missing = policy is None and not args.no_policy
    if policy is not None:
        check_policy(policy)
    low, high = args.push_interval
    if low > high:
        raise ConfigError(f"--push-interval MIN MAX: MIN {low:g} s is above MAX {high:g} s")
    if args.plot:
        check_plot_path(args.plot)  # before the run, not after it
    pushes = PushSetting(args.push_force, args.push_duration, (low, high))
    total = args.episodes * len(args.conditions) * (1 if policy is None else len(CONTROLLERS))
    started = time.perf_counter()
    with connect(args.ray) if args.ray else nullcontext() as connection, \
            Progress(total, "sim-to-sim", enabled=wants_progress(args) and not connection) as bar:  # Ray: no live count
        cells = evaluate(policy=policy, episodes=args.episodes, seconds=args.seconds, pushes=pushes, workers=args.workers,
                         seed=args.seed, conditions=args.conditions, runner=RayRunner(connection) if connection else None,
                         progress=bar if bar.enabled else None)
        workers = connection.cpus if connection else args.workers
    wall = time.perf_counter() - started
    if args.plot:
        save_figure(sim_to_sim_figure(cells), args.plot)
    if not args.json:
        print(markdown_table(cells, missing))
        print(f"each cell: episodes that ran their {pushes.episode_seconds(args.seconds):g} s without falling / episodes (pushes "
              f"starting in the first {args.seconds:g} s, then {SETTLE_AFTER_PUSH_S:g} s after the last push's end), seeds "
              f"{args.seed}..{args.seed + args.episodes - 1}; pushes of {pushes.force:g} N for {pushes.duration:g} s every "
              f"{low:g}-{high:g} s; policy: {policy or 'none'}")
        return 0
    print(json.dumps({
        "benchmark": "sim_to_sim",
        "env": ENV_ID,
        "policy": policy,
        "policy_missing": missing,
        "episodes": args.episodes,
        "seconds_per_episode": args.seconds,  # pushes start within these; the episode runs on to the settle window
        "episode_seconds": pushes.episode_seconds(args.seconds),
        "settle_after_push_s": SETTLE_AFTER_PUSH_S,
        "pushes": asdict(pushes),
        "workers": workers,
        "ray": args.ray,
        "seed": args.seed,
        "wall_s": wall,
        "results": {controller: {condition: cell.summary() for condition, cell in row.items()} for controller, row in cells.items()},
    }))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="sim_to_sim", description=__doc__, formatter_class=HelpFormatter)
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run_sim_to_sim_command(args)
    except (ConfigError, PolicyFormatError) as error:
        print(f"sim_to_sim: error: {error}", file=sys.stderr)
        return 2
