"""Walking and push recovery by stepping (the G1 in MuJoCo): speeds, tracking, falls, push success.

Usage: ``python benchmarks/locomotion.py [--full] [--seeds N] [--seconds S] [--episodes N]
[--parts walking,push,walking_push,tick] [--workers N] [--seed-base S]``. Prints ONE JSON object;
every figure comes with the seeds it was measured on: every part draws its seeds from
``--seed-base`` on (default 2000: never the tuning seeds below 1000, nor the integrator's fresh
seeds 1000-1999).

* **walking**: commanded 0.3 / 0.5 / 0.7 m/s forward, 0.2 m/s lateral, 0.5 rad/s turning; per
  seeded run (initial joint angles and base velocity perturbed from the seed) the mean per-step
  velocity (heading frame), the velocity-tracking error two ways over the same steps (after the
  first two): ``tracking_rms_per_step`` (base xy velocity averaged over each step vs the command)
  and per tick in the heading frame (``tracking_rms_per_tick_heading_xy`` and mean absolute, yaw
  rate likewise: every 2 ms tick's instantaneous velocity, mjlab's ``track_lin_vel_xy``), falls.
  Commands beyond the gait limits are clamped (reported).
* **push**: standing, one push of 0.2 s on the pelvis, start uniform in [1.2, 1.6] s, random
  horizontal direction (the ``giwbc evaluate`` protocol's push), the episode running on
  ``SETTLE_AFTER_PUSH_S`` (3 s) after the push ends; success: no fall and final tilt below
  0.35 rad; stepping vs the feet-in-place balance controller on the same seeds; and 60 N straight
  backward. Each fall is reported in s after the push ended.
* **walking_push**: at 0.3 m/s, one push of 0.2 s at a random time in [2, 3] s, random
  direction, the episode running on 3 s after the push ends: success = no fall.
* **tick**: the WBC tick (wall clock, one thread) in single support, in double support and at
  contact switches while walking, beside the standing (feet-in-place) double-support tick of the
  same process.

Default: a short run (1 seed × 10 s per command, 10 push episodes per force); ``--full`` is the
issue's protocol (10 seeds × 20 s, 100 episodes per force) — long on a small machine.
"""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_variable] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402

import giwbc  # noqa: E402,F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
import numpy as np  # noqa: E402

from giwbc.apps.progress import Progress, add_progress_argument, wants_progress  # noqa: E402
from giwbc.locomotion.push_scoring import SETTLE_AFTER_PUSH_S, fall_times_summary, judge_push  # noqa: E402
from giwbc.locomotion.simulation import Push, simulate_walk  # noqa: E402
from giwbc.locomotion.walker import WalkerConfig  # noqa: E402
from giwbc.robot import load  # noqa: E402

COMMANDS = {"forward_0.3": (0.3, 0.0, 0.0), "forward_0.5": (0.5, 0.0, 0.0), "forward_0.7": (0.7, 0.0, 0.0), "lateral_0.2": (0.0, 0.2, 0.0), "turn_0.5": (0.0, 0.0, 0.5)}
SEED_BASE = 2000  # every part's seeds start here (tuning used seeds < 1000; 1000-1999 are kept fresh)
UPRIGHT_TILT = 0.35
PUSH_SECONDS = 0.2
PER_TICK = ("tracking_rms_per_tick_heading_xy", "tracking_mean_abs_per_tick_heading_xy", "yaw_rate_rms_per_tick", "yaw_rate_mean_abs_per_tick")


def _walk(job: tuple[str, tuple[float, float, float], float, int]) -> dict:
    name, command, seconds, seed = job
    run = simulate_walk(load("g1"), command, seconds, seed=seed)
    return {
        "command": name, "seed": seed, "fell": run.fell, "fall_time": run.fall_time, "steps": run.steps,
        "mean_velocity": [round(float(x), 4) for x in run.mean_velocity], "mean_yaw_rate": round(run.mean_yaw_rate, 4),
        "tracking_rms_per_step": round(run.tracking_rms, 4), "yaw_rate_rms_per_step": round(run.yaw_rate_rms, 4),
        **{key: round(getattr(run.per_tick, key), 4) for key in PER_TICK}, "wbc_failures": run.wbc_failures,
        "notes": run.notes, "ticks": _tick_split(run),
    }


def _tick_split(run) -> dict:
    t = run.tick_seconds
    walking = np.arange(len(t)) > int(1.0 / 0.002)
    return {"single": t[walking & run.single_support_ticks].tolist(), "double": t[walking & ~run.single_support_ticks].tolist(), "switch": t[run.switch_ticks].tolist()}


def _push_episode(job: tuple[float, int, bool, float | None, bool]) -> dict:
    force, seed, stepping, direction, walking = job
    rng = np.random.default_rng(seed)
    if walking:
        start, angle = float(rng.uniform(2.0, 3.0)), float(rng.uniform(-math.pi, math.pi))
        command, command_start = (0.3, 0.0, 0.0), 0.5
    else:
        start, angle = float(rng.uniform(1.2, 1.6)), float(rng.uniform(-math.pi, math.pi))
        command, command_start = (0.0, 0.0, 0.0), None
    if direction is not None:
        angle = direction
    push_end = start + PUSH_SECONDS
    seconds = push_end + SETTLE_AFTER_PUSH_S + 0.005  # a few ticks over: the run's tick count is rounded
    run = simulate_walk(load("g1"), command, seconds, pushes=(Push(start, force, angle, PUSH_SECONDS),), command_start=command_start,
                        stepping=stepping, seed=seed)
    outcome = judge_push(fell=run.fell, fall_time=run.fall_time, end_time=run.seconds, push_end=push_end, final_tilt=run.final_tilt,
                         upright_tilt=math.inf if walking else UPRIGHT_TILT)
    return {"force": force, "seed": seed, "stepping": stepping, "success": outcome.success, "fell": run.fell,
            "fall_after_push": None if outcome.fall_after_push is None else round(outcome.fall_after_push, 3), "steps": run.steps,
            "push_start": round(start, 3), "direction": round(angle, 3)}


def _map(function, jobs: list, workers: int, progress: bool = False) -> list:
    """``[function(job) for job in jobs]`` on ``workers`` processes, with a bar of jobs done on a terminal."""
    with Progress(len(jobs), function.__name__.strip("_"), unit="run", enabled=progress) as bar:
        if workers <= 1:
            results = []
            for job in jobs:
                results.append(function(job))
                bar(1)
            return results
        with ProcessPoolExecutor(workers) as pool:
            results = []
            for result in pool.map(function, jobs):  # in order: the bar moves as the earliest jobs end
                results.append(result)
                bar(1)
            return results


def _stats(values_s: list[float]) -> dict | None:
    if not values_s:
        return None
    us = np.asarray(values_s) * 1e6
    return {"median_us": round(float(np.median(us)), 1), "p99_us": round(float(np.percentile(us, 99)), 1), "n": len(us)}


def _wilson(successes: int, n: int) -> list[float]:
    if n == 0:
        return [math.nan, math.nan]
    z = 1.96
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return [round(max(0.0, centre - half), 3), round(min(1.0, centre + half), 3)]  # no -0.0 from rounding


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--full", action="store_true", help="the issue's protocol: 10 seeds x 20 s, 100 push episodes per force")
    parser.add_argument("--seeds", type=int, default=None, help="walking runs per command (default 1, --full 10)")
    parser.add_argument("--seconds", type=float, default=None, help="length of a walking run (default 10, --full 20)")
    parser.add_argument("--episodes", type=int, default=None, help="push episodes per force and arm (default 10, --full 100)")
    parser.add_argument("--forces", type=float, nargs="+", default=[80.0, 100.0, 150.0])
    parser.add_argument("--parts", default="walking,push,walking_push,tick")
    parser.add_argument("--commands", default=",".join(COMMANDS), help=f"walking commands among {list(COMMANDS)}")
    parser.add_argument("--workers", type=int, default=1, help="processes (the machine has %d CPUs)" % (os.cpu_count() or 1))
    add_progress_argument(parser)
    parser.add_argument("--seed-base", type=int, default=SEED_BASE, help="first seed of every part")
    args = parser.parse_args(argv)
    progress = wants_progress(args)
    seeds = args.seeds if args.seeds is not None else (10 if args.full else 1)
    seconds = args.seconds if args.seconds is not None else (20.0 if args.full else 10.0)
    episodes = args.episodes if args.episodes is not None else (100 if args.full else 10)
    parts = set(args.parts.split(","))
    base = args.seed_base
    out: dict = {"benchmark": "locomotion", "robot": "g1", "machine": platform.machine(), "python": platform.python_version(), "cpus": os.cpu_count(),
                 "full_protocol": bool(args.full), "argv": sys.argv[1:] if argv is None else argv, "seed_base": base}
    started = time.perf_counter()
    walk_results: list[dict] = []
    if "walking" in parts or "tick" in parts:
        names = args.commands.split(",") if "walking" in parts else ["forward_0.3"]
        jobs = [(name, COMMANDS[name], seconds, base + i) for name in names for i in range(seeds)]
        walk_results = _map(_walk, jobs, args.workers, progress)
    if "walking" in parts:
        walking = {}
        for name in args.commands.split(","):
            runs = [r for r in walk_results if r["command"] == name]
            velocities = np.array([r["mean_velocity"] for r in runs], dtype=float)
            walking[name] = {
                "command": COMMANDS[name], "seconds": seconds, "seeds": [r["seed"] for r in runs],
                "falls": sum(r["fell"] for r in runs),
                "mean_velocity": [round(float(x), 3) for x in np.nanmean(velocities, axis=0)] if len(runs) else None,
                "mean_yaw_rate": round(float(np.nanmean([r["mean_yaw_rate"] for r in runs])), 3),
                "tracking_rms_per_step": round(float(np.sqrt(np.nanmean([r["tracking_rms_per_step"] ** 2 for r in runs]))), 4),
                "yaw_rate_rms_per_step": round(float(np.sqrt(np.nanmean([r["yaw_rate_rms_per_step"] ** 2 for r in runs]))), 4),
                # per tick, pooled over the runs (RMS of the runs' RMS, mean of their means: runs of equal length)
                **{key: round(float(np.sqrt(np.nanmean([r[key] ** 2 for r in runs])) if "rms" in key else np.nanmean([r[key] for r in runs])), 4)
                   for key in PER_TICK},
                "wbc_failures": sum(r["wbc_failures"] for r in runs),
                "clamped": sorted({n for r in runs for n in r["notes"]}),
                "runs": [{k: r[k] for k in ("seed", "fell", "fall_time", "steps", "mean_velocity", "mean_yaw_rate", "tracking_rms_per_step",
                                            "tracking_rms_per_tick_heading_xy")} for r in runs],
            }
        out["walking"] = walking
    if "push" in parts:
        jobs = [(force, base + i, stepping, None, False) for force in args.forces for stepping in (True, False) for i in range(episodes)]
        jobs += [(60.0, base + i, stepping, math.pi, False) for stepping in (True, False) for i in range(max(1, min(episodes, 10)))]
        results = _map(_push_episode, jobs, args.workers, progress)
        push: dict = {"protocol": {"duration": PUSH_SECONDS, "start": [1.2, 1.6], "settle_after_push_s": SETTLE_AFTER_PUSH_S,
                                   "upright_tilt": UPRIGHT_TILT, "direction": "uniform"}}
        for force in args.forces + [60.0]:
            label = f"{force:g}N" if force != 60.0 or 60.0 in args.forces else "60N_backward"
            row = {}
            for stepping in (True, False):
                rs = [r for r in results if r["force"] == force and r["stepping"] == stepping and (label != "60N_backward" or r["direction"] == round(math.pi, 3))]
                wins = sum(r["success"] for r in rs)
                row["stepping" if stepping else "feet_in_place"] = {"success": wins, "episodes": len(rs), "rate": round(wins / len(rs), 3) if rs else None, "ci95": _wilson(wins, len(rs)), "mean_steps": round(float(np.mean([r["steps"] for r in rs])), 2) if rs else None,
                                                                    **fall_times_summary([r["fall_after_push"] for r in rs if r["fall_after_push"] is not None])}
            row["seeds"] = [base, base + (episodes if label != "60N_backward" else max(1, min(episodes, 10))) - 1]
            push[label] = row
        out["push_standing"] = push
    if "walking_push" in parts:
        jobs = [(80.0, base + i, True, None, True) for i in range(episodes)]
        results = _map(_push_episode, jobs, args.workers, progress)
        wins = sum(r["success"] for r in results)
        out["push_walking"] = {"speed": 0.3, "force": 80.0, "duration": PUSH_SECONDS, "settle_after_push_s": SETTLE_AFTER_PUSH_S, "success": wins, "episodes": len(results), "rate": round(wins / len(results), 3), "ci95": _wilson(wins, len(results)), "seeds": [base, base + episodes - 1],
                               **fall_times_summary([r["fall_after_push"] for r in results if r["fall_after_push"] is not None])}
    if "tick" in parts:
        single = [x for r in walk_results for x in r["ticks"]["single"]]
        double = [x for r in walk_results for x in r["ticks"]["double"]]
        switch = [x for r in walk_results for x in r["ticks"]["switch"]]
        standing = simulate_walk(load("g1"), (0.0, 0.0, 0.0), 3.0, command_start=None, stepping=False)
        dropped = _tick_split(simulate_walk(load("g1"), COMMANDS["forward_0.3"], 6.0, seed=base, config=WalkerConfig(drop_swing_contact=True)))
        out["wbc_tick"] = {
            "walking_single_support": _stats(single), "walking_double_support": _stats(double), "contact_switch": _stats(switch),
            "drop_swing_contact": {"single_support": _stats(dropped["single"]), "double_support": _stats(dropped["double"]), "contact_switch": _stats(dropped["switch"]), "seed": base, "command": "forward_0.3"},
            "standing_feet_in_place_double_support": _stats(standing.tick_seconds[100:].tolist()),
            "note": "wall-clock WBC ticks inside the simulation loop (MuJoCo steps between ticks), one thread, not pinned; compare within this run only",
        }
    out["wall_seconds"] = round(time.perf_counter() - started, 1)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
