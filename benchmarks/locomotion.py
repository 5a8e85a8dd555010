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
* **gait_phase** (issue 38): pushes of ``--impulse`` N s (default 30) over 0.1 s in 8 directions
  (from the heading) at 5 phases (0, 0.2, ... 0.8 of the left-to-left step pair from the first left
  touch-down after 2.5 s, read from the walker's own contact schedule in the unpushed run of the
  same seed), stepping in place and walking at 0.5 m/s; success by ``judge_push`` (3 s after the
  push); per condition with Wilson 95 % intervals, per phase and per direction.
* **impulse_grid**: standing (stepping walker), 0.1 s pushes in 8 directions at 25 / 30 / 35 N s
  (``--impulses``), ``--grid-seeds`` seeds per cell (default 3).
* **envelope**: the 23 commands of ``ENVELOPE_GRID`` (``--envelope-commands``: some of them; vx 1.0 / -0.5, vy +-0.4, wz +-1.0,
  combinations) for 12 s (``--envelope-seconds``; --full 20 s x 10 seeds): falls, the command
  followed after the clamp, mean heading-frame velocity after the first 3 s against it, tracking per
  step and per tick. Every metric's definition is in the output's ``definitions``.
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


def _push_episode(job: tuple) -> dict:
    """``(force, seed, stepping, direction or None, walking[, duration s])``: one pushed episode, judged by judge_push."""
    force, seed, stepping, direction, walking, *rest = job
    duration = float(rest[0]) if rest else PUSH_SECONDS
    rng = np.random.default_rng(seed)
    if walking:
        start, angle = float(rng.uniform(2.0, 3.0)), float(rng.uniform(-math.pi, math.pi))
        command, command_start = (0.3, 0.0, 0.0), 0.5
    else:
        start, angle = float(rng.uniform(1.2, 1.6)), float(rng.uniform(-math.pi, math.pi))
        command, command_start = (0.0, 0.0, 0.0), None
    if direction is not None:
        angle = direction
    push_end = start + duration
    seconds = push_end + SETTLE_AFTER_PUSH_S + 0.005  # a few ticks over: the run's tick count is rounded
    run = simulate_walk(load("g1"), command, seconds, pushes=(Push(start, force, angle, duration),), command_start=command_start,
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


# ---- pushes at gait phases, the standing impulse grid, the envelope grid (issue 38) ----

PHASES = (0.0, 0.2, 0.4, 0.6, 0.8)  # fractions of a left-right step pair from a left touch-down
DIRECTIONS = tuple(k * math.pi / 4 for k in range(8))  # rad from the heading (0 forward, pi/2 left)
GRID_PUSH_SECONDS = 0.1
PHASE_CONDITIONS = {"stepping_in_place": ((0.0, 0.0, 0.0), True), "walking_0.5": ((0.5, 0.0, 0.0), False)}
PHASE_ANCHOR_S = 2.5  # the push's step pair starts at the first left touch-down at or after this
ENVELOPE_GRID = {
    "vx_0.3": (0.3, 0.0, 0.0), "vx_0.5": (0.5, 0.0, 0.0), "vx_0.7": (0.7, 0.0, 0.0), "vx_1.0": (1.0, 0.0, 0.0),
    "vx_-0.3": (-0.3, 0.0, 0.0), "vx_-0.5": (-0.5, 0.0, 0.0), "vy_0.2": (0.0, 0.2, 0.0), "vy_-0.2": (0.0, -0.2, 0.0),
    "vy_0.4": (0.0, 0.4, 0.0), "vy_-0.4": (0.0, -0.4, 0.0), "wz_0.5": (0.0, 0.0, 0.5), "wz_-0.5": (0.0, 0.0, -0.5),
    "wz_1.0": (0.0, 0.0, 1.0), "wz_-1.0": (0.0, 0.0, -1.0), "vx_0.5_wz_0.5": (0.5, 0.0, 0.5), "vx_0.5_wz_-0.5": (0.5, 0.0, -0.5),
    "vx_0.5_vy_0.2": (0.5, 0.2, 0.0), "vx_0.3_vy_-0.2": (0.3, -0.2, 0.0), "vx_-0.3_wz_0.5": (-0.3, 0.0, 0.5),
    "vx_0.3_vy_0.2_wz_0.5": (0.3, 0.2, 0.5), "vx_1.0_wz_1.0": (1.0, 0.0, 1.0), "vx_-0.5_vy_0.4": (-0.5, 0.4, 0.0),
    "vy_0.4_wz_1.0": (0.0, 0.4, 1.0),
}
ENVELOPE_DISCARD_S = 3.0
METRIC_DEFINITIONS = {
    "push_phase": "the push start's fraction of the step pair [t_L, t_L'), t_L the walker's last left touch-down at or before it and t_L' "
                  "the next one, both from the unpushed run of the same seed (bit-identical to the pushed run up to the push); a touch-down is "
                  "the tick the walker's step counter increments, the foot the one that swung",
    "push_direction": "rad from the base heading at the push start in the unpushed run (0 forward, pi/2 left)",
    "success": "judge_push: no fall (base below 65 % of its standing height or tilt > 45 deg) up to >= SETTLE_AFTER_PUSH_S after the push "
               "ends, and (standing only) final tilt < upright_tilt",
    "ci95": "Wilson score interval, z = 1.96",
    "envelope_mean_velocity": "mean over the ticks after the first ENVELOPE_DISCARD_S s of the run of the base's ground-truth velocity in the "
                              "heading frame (vx, vy) and of its yaw rate",
    "envelope_within": "|mean - command followed| <= max(0.05 |command followed|, 0.03) for each of vx, vy (m/s) and wz (rad/s)",
    "command_followed": "the walker's command after the gait envelope's clamp",
    "tracking_rms_per_step": "RMS over steps (after the first two) of |per-step mean base xy velocity (heading frame) - command followed|",
    "tracking_rms_per_tick_heading_xy": "RMS over 2 ms ticks (same span) of |instantaneous base xy velocity (heading frame) - command followed| "
                                        "(mjlab's track_lin_vel_xy); mean_abs likewise; yaw_rate_* the same for the yaw rate",
}


class ContactSchedule:
    """An ``observe`` hook for :func:`simulate_walk`: the walker's touch-downs (time s, side) and the base yaw of every tick."""

    def __init__(self) -> None:
        self.touchdowns: list[tuple[float, str]] = []
        self.yaw: list[float] = []
        self._steps = 0
        self._stance: str | None = None

    def __call__(self, robot, controller) -> None:
        state = controller.state
        if state.steps != self._steps:
            self._steps = state.steps
            if self._stance is not None:  # the foot that touched down is the one that swung
                self.touchdowns.append((robot.time(), "right" if self._stance == "left" else "left"))
        if state.phase.name == "SINGLE":
            self._stance = state.stance
        rotation = robot.base_state().rotation
        self.yaw.append(math.atan2(rotation[1, 0], rotation[0, 0]))


def step_pair(time_s: float, touchdowns: list[tuple[float, str]]) -> tuple[float, float]:
    """The left-to-left step pair holding ``time_s``: (last left touch-down at or before it, the next left touch-down).
    ValueError when the schedule does not hold one."""
    lefts = np.array(sorted(t for t, side in touchdowns if side == "left"))
    i = int(np.searchsorted(lefts, time_s, side="right")) - 1
    if i < 0 or i + 1 >= len(lefts):
        raise ValueError(f"no left-to-left step pair holds t = {time_s:.3f} s in this contact schedule")
    return float(lefts[i]), float(lefts[i + 1])


def push_phase(time_s: float, touchdowns: list[tuple[float, str]]) -> float:
    """The phase in [0, 1) of ``time_s`` in the walker's gait: its fraction of the left-to-left step pair holding it."""
    t0, t1 = step_pair(time_s, touchdowns)
    return (time_s - t0) / (t1 - t0)


def phase_start(phase: float, touchdowns: list[tuple[float, str]], anchor: float) -> float:
    """The time at ``phase`` of the step pair starting at the first left touch-down at or after ``anchor`` s."""
    lefts = [t for t, side in touchdowns if side == "left" and t >= anchor]
    if len(lefts) < 2:
        raise ValueError(f"the contact schedule has no full step pair after {anchor:g} s")
    return lefts[0] + phase * (lefts[1] - lefts[0])


def success_table(results: list[dict], key: str) -> dict:
    """Success by ``key`` (e.g. phase, direction): per value the successes, episodes, rate and Wilson 95 % interval."""
    table: dict = {}
    for value in sorted({r[key] for r in results}):
        rs = [r for r in results if r[key] == value]
        wins = sum(bool(r["success"]) for r in rs)
        table[f"{value:g}" if isinstance(value, float) else str(value)] = {"success": wins, "episodes": len(rs), "rate": round(wins / len(rs), 3), "ci95": _wilson(wins, len(rs))}
    return table


def _reference(job: tuple[str, int]) -> dict:
    """The unpushed run of a gait-phase condition and seed: its contact schedule and headings."""
    condition, seed = job
    command, in_place = PHASE_CONDITIONS[condition]
    schedule = ContactSchedule()
    run = simulate_walk(load("g1"), command, PHASE_ANCHOR_S + 2.5, step_in_place=in_place, seed=seed, observe=schedule)
    return {"condition": condition, "seed": seed, "fell": run.fell, "touchdowns": schedule.touchdowns, "yaw": schedule.yaw}


def _phase_episode(job: tuple[str, int, float, float, float, float, float]) -> dict:
    """A pushed episode of the gait-phase protocol: ``(condition, seed, phase, direction from heading, push start, heading, impulse)``."""
    condition, seed, phase, direction, start, heading, impulse = job
    command, in_place = PHASE_CONDITIONS[condition]
    push = Push(start, impulse / GRID_PUSH_SECONDS, heading + direction, GRID_PUSH_SECONDS)
    push_end = start + GRID_PUSH_SECONDS
    schedule = ContactSchedule()
    run = simulate_walk(load("g1"), command, push_end + SETTLE_AFTER_PUSH_S + 0.005, pushes=(push,), step_in_place=in_place, seed=seed, observe=schedule)
    outcome = judge_push(fell=run.fell, fall_time=run.fall_time, end_time=run.seconds, push_end=push_end)
    before = [(t, side) for t, side in schedule.touchdowns if t <= start]
    return {"condition": condition, "seed": seed, "phase": phase, "direction": round(direction, 3), "push_start": round(start, 3),
            "success": outcome.success, "fall_after_push": None if outcome.fall_after_push is None else round(outcome.fall_after_push, 3),
            "last_left_touchdown": max((t for t, side in before if side == "left"), default=None)}


def gait_phase_protocol(seeds: list[int], impulse: float, workers: int, progress: bool) -> dict:
    """Pushes of ``impulse`` N s over 0.1 s at PHASES x DIRECTIONS, stepping in place and walking at 0.5 m/s, per seed."""
    references = _map(_reference, [(c, s) for c in PHASE_CONDITIONS for s in seeds], workers, progress)
    jobs, skipped = [], []
    for ref in references:
        if ref["fell"]:
            skipped.append({"condition": ref["condition"], "seed": ref["seed"], "why": "the unpushed run fell"})
            continue
        for phase in PHASES:
            start = phase_start(phase, ref["touchdowns"], PHASE_ANCHOR_S)
            heading = ref["yaw"][min(int(round(start / 0.002)), len(ref["yaw"]) - 1)]
            jobs += [(ref["condition"], ref["seed"], phase, d, start, heading, impulse) for d in DIRECTIONS]
    results = _map(_phase_episode, jobs, workers, progress)
    out: dict = {"impulse_Ns": impulse, "duration_s": GRID_PUSH_SECONDS, "force_N": impulse / GRID_PUSH_SECONDS, "phases": list(PHASES),
                 "directions_rad": [round(d, 3) for d in DIRECTIONS], "anchor_s": PHASE_ANCHOR_S, "settle_after_push_s": SETTLE_AFTER_PUSH_S,
                 "seeds": seeds, "skipped": skipped}
    for condition in PHASE_CONDITIONS:
        rs = [r for r in results if r["condition"] == condition]
        if not rs:
            continue
        wins = sum(r["success"] for r in rs)
        out[condition] = {"success": wins, "episodes": len(rs), "rate": round(wins / len(rs), 3), "ci95": _wilson(wins, len(rs)),
                          "by_phase": success_table(rs, "phase"), "by_direction": success_table(rs, "direction"),
                          **fall_times_summary([r["fall_after_push"] for r in rs if r["fall_after_push"] is not None]),
                          "failures": [{k: r[k] for k in ("seed", "phase", "direction", "fall_after_push")} for r in rs if not r["success"]]}
    return out


def impulse_grid(impulses: list[float], seeds: list[int], workers: int, progress: bool) -> dict:
    """Standing (stepping walker), 0.1 s pushes in 8 directions (world; the robot starts facing +x) at each impulse, per seed."""
    jobs = [(i / GRID_PUSH_SECONDS, s, True, d, False, GRID_PUSH_SECONDS) for i in impulses for d in DIRECTIONS for s in seeds]
    results = _map(_push_episode, jobs, workers, progress)
    for r in results:
        r["impulse"] = round(r["force"] * GRID_PUSH_SECONDS, 3)
    out: dict = {"duration_s": GRID_PUSH_SECONDS, "start": [1.2, 1.6], "upright_tilt": UPRIGHT_TILT, "settle_after_push_s": SETTLE_AFTER_PUSH_S, "seeds": seeds}
    for impulse in impulses:
        rs = [r for r in results if r["impulse"] == round(impulse, 3)]
        wins = sum(r["success"] for r in rs)
        out[f"{impulse:g}Ns"] = {"success": wins, "episodes": len(rs), "rate": round(wins / len(rs), 3), "ci95": _wilson(wins, len(rs)),
                                 "by_direction": success_table(rs, "direction"),
                                 **fall_times_summary([r["fall_after_push"] for r in rs if r["fall_after_push"] is not None])}
    return out


class _HeadingVelocity:
    """An ``observe`` hook: the base's heading-frame velocity and yaw rate summed over the ticks after ``discard`` s, and the command followed."""

    def __init__(self, discard: float) -> None:
        self.discard, self.sum, self.n, self.command = discard, np.zeros(3), 0, (math.nan,) * 3

    def __call__(self, robot, controller) -> None:
        if robot.time() <= self.discard:
            return
        base = robot.base_state()
        c, s = base.rotation[0, 0], base.rotation[1, 0]
        norm = math.hypot(c, s)
        v = base.linear_velocity
        self.sum += ((c * v[0] + s * v[1]) / norm, (-s * v[0] + c * v[1]) / norm, base.angular_velocity[2])
        self.n += 1
        cmd = controller.command
        self.command = (cmd.vx, cmd.vy, cmd.yaw_rate)


def _envelope_run(job: tuple[str, tuple[float, float, float], float, int]) -> dict:
    name, command, seconds, seed = job
    hook = _HeadingVelocity(ENVELOPE_DISCARD_S)
    run = simulate_walk(load("g1"), command, seconds, seed=seed, observe=hook)
    mean = hook.sum / max(hook.n, 1)
    followed = np.array(hook.command)
    within = bool(np.all(np.abs(mean - followed) <= np.maximum(0.05 * np.abs(followed), 0.03)))
    return {"command": list(command), "seed": seed, "fell": run.fell, "fall_time": run.fall_time, "command_followed": [round(float(x), 3) for x in followed],
            "clamped": bool(np.any(np.abs(followed - np.array(command)) > 1e-9)), "notes": run.notes,
            "mean_velocity": [round(float(x), 3) for x in mean], "within": within, "steps": run.steps,
            "tracking_rms_per_step": round(run.tracking_rms, 4), "yaw_rate_rms_per_step": round(run.yaw_rate_rms, 4),
            **{key: round(getattr(run.per_tick, key), 4) for key in PER_TICK}}


def envelope_grid(seconds: float, seeds: list[int], workers: int, progress: bool, names: list[str] | None = None) -> dict:
    """Every command of ENVELOPE_GRID (or those ``names``) for ``seconds`` per seed: falls, command followed, mean velocity vs it, tracking both ways."""
    grid = ENVELOPE_GRID if names is None else {name: ENVELOPE_GRID[name] for name in names}
    jobs = [(name, command, seconds, s) for name, command in grid.items() for s in seeds]
    results = _map(_envelope_run, jobs, workers, progress)
    runs = {}
    for (name, *_), r in zip(jobs, results):
        runs.setdefault(name, []).append(r)
    return {"seconds": seconds, "discard_s": ENVELOPE_DISCARD_S, "seeds": seeds, "commands": len(grid),
            "falls": sum(r["fell"] for r in results), "runs_total": len(results), "within": sum(r["within"] and not r["fell"] for r in results),
            "runs": runs}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--full", action="store_true", help="the issue's protocol: 10 seeds x 20 s, 100 push episodes per force")
    parser.add_argument("--seeds", type=int, default=None, help="walking runs per command (default 1, --full 10)")
    parser.add_argument("--seconds", type=float, default=None, help="length of a walking run (default 10, --full 20)")
    parser.add_argument("--episodes", type=int, default=None, help="push episodes per force and arm (default 10, --full 100)")
    parser.add_argument("--forces", type=float, nargs="+", default=[80.0, 100.0, 150.0])
    parser.add_argument("--parts", default="walking,push,walking_push,tick", help="among walking, push, walking_push, tick, gait_phase, impulse_grid, envelope")
    parser.add_argument("--commands", default=",".join(COMMANDS), help=f"walking commands among {list(COMMANDS)}")
    parser.add_argument("--workers", type=int, default=1, help="processes (the machine has %d CPUs)" % (os.cpu_count() or 1))
    add_progress_argument(parser)
    parser.add_argument("--seed-base", type=int, default=SEED_BASE, help="first seed of every part")
    parser.add_argument("--grid-seeds", type=int, default=None, help="seeds per cell of gait_phase / impulse_grid / envelope (default 1, --full 3 / 3 / 10)")
    parser.add_argument("--impulse", type=float, default=30.0, help="gait_phase push impulse, N s (over 0.1 s)")
    parser.add_argument("--impulses", type=float, nargs="+", default=[25.0, 30.0, 35.0], help="impulse_grid impulses, N s (over 0.1 s)")
    parser.add_argument("--envelope-commands", nargs="+", choices=list(ENVELOPE_GRID), default=None, metavar="NAME",
                        help=f"envelope commands to run (default all): {', '.join(ENVELOPE_GRID)}")
    parser.add_argument("--envelope-seconds", type=float, default=None, help="envelope run length (default 12, --full 20)")
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
    if "gait_phase" in parts:
        n = args.grid_seeds if args.grid_seeds is not None else (3 if args.full else 1)
        out["push_gait_phase"] = gait_phase_protocol([base + i for i in range(n)], args.impulse, args.workers, progress)
    if "impulse_grid" in parts:
        n = args.grid_seeds if args.grid_seeds is not None else 3
        out["push_impulse_grid"] = impulse_grid(args.impulses, [base + i for i in range(n)], args.workers, progress)
    if "envelope" in parts:
        n = args.grid_seeds if args.grid_seeds is not None else (10 if args.full else 1)
        length = args.envelope_seconds if args.envelope_seconds is not None else (20.0 if args.full else 12.0)
        out["envelope_grid"] = envelope_grid(length, [base + i for i in range(n)], args.workers, progress, args.envelope_commands)
    if parts & {"gait_phase", "impulse_grid", "envelope"}:
        out["definitions"] = METRIC_DEFINITIONS
    out["wall_seconds"] = round(time.perf_counter() - started, 1)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
