"""The controller on plants it was not tuned on: standing, walking and push protocols on every
shipped plant variant (``robots/<robot>/plants``) and the nominal plant, same seeds on each.

Protocols (the plant-mismatch issue's), each run by :func:`giwbc.locomotion.simulation.simulate_walk`
(the walker on the WBC, MuJoCo ground truth), seeds ``seed_base + i``, the start perturbed by the seed:

* **stand**: zero command, ``--stand-seconds`` (10 s);
* **walk**: forward 0.3 and 0.5 m/s, turning in place 0.3 rad/s, ``--walk-seconds`` (20 s), command from 0.5 s;
* **push**: standing, one push of ``--push-force`` N (100) x 0.2 s at 2 s towards each of
  ``--directions`` directions (8, evenly spaced from 0), the walker free to step; success = not
  fallen ``--judge-after`` s (3) after the push ends, the run stopping there.

Figures per plant and protocol (JSON, one object; ``definitions`` repeats these):

* ``falls``: runs ending with the base below 65 % of its standing height or tilted over 45 deg;
* ``max_foot_tilt_deg``: the largest angle between a foot's sole normal (its link's z axis) and the
  vertical while that foot is loaded (touch sensor > 20 N), over every tick of every run after the
  first 0.5 s (the seeded start settling);
* ``max_foot_slip_mm``: the largest horizontal travel of a loaded foot's sole centre from where it
  was when that load began (one stance), over every stance of every run;
* ``step_tracking_rms``: simulate_walk's per-step tracking (the base xy velocity averaged over each
  step in the heading frame of its start, against the command; RMS over the steps after the first
  two), RMS over runs that did not fall;
* ``tick_tracking_rms``: per tick from 2 s after the command, the base xy velocity in the heading
  frame (base yaw) against the command, RMS over ticks of runs that did not fall (sways within a
  step count: larger than the per-step figure); ``tick_yaw_rate_rms`` the same for the yaw rate;
* ``push_success``: successes / pushes, with its 95 % Wilson interval.

``--estimator``: the same protocols through ``giwbc/G1Walk-v0`` in the shipped walking policy's
training conditions (its metadata: the deployment walker on the **estimated** state, the AHRS IMU
profile, WBC joint limits and soft-limit ends) with the zero residual (the walker alone);
``--policy P``: walker alone vs policy ``P`` (its own metadata's conditions), paired: the same seeds and
plant draws in both arms, each cell's figures per arm (``walker``, ``policy``) and ``paired``: each
arm's successes (push: not fallen ``--judge-after`` s after the push ends; stand and walk: not fallen)
with 95 % Wilson intervals, the discordant pairs (``saved``, ``lost``) and the exact McNemar p-value,
also per drawn plant. ``--plants random`` (env path only): a plant drawn per episode from the seed out
of the robot's plant distribution (``robots/<robot>/plant_distribution.toml``). Both sample the
ground truth at the agent rate (50 Hz) instead of every physics tick, push in a seeded random
direction (the environment's pushes) instead of the fixed directions, count any early end (a fall or
a soft-limit end) as a fall, and add the estimator's errors: ``estimator_tilt_error_deg`` (max),
``estimator_velocity_error_rms`` (base xy, m/s), ``estimator_height_error_max_m``,
``estimator_height_drift_max_m`` (the height error's largest change from its first sampled value)
and its contact decisions against the touch sensors (``estimator_contact_agreement``,
``estimator_false_stance``: a foot taken as standing that carries under 20 N, ``estimator_missed_stance``).

``--walker any_floor``: the walker preset for floors and feet it was not tuned on (a friction of 0.5,
giwbc.locomotion.walker_config.ANY_FLOOR_OPTIONS) instead of its defaults.

Run: ``python benchmarks/robustness.py --runs 10`` (the issue's size: ~hours on 2 vCPUs);
``--runs 2 --directions 4`` for a quick table. Use fresh seeds (>= 20000: never tuned on).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from giwbc.apps.evaluation import mcnemar_exact, wilson_interval  # noqa: E402
from giwbc.errors import EstimatorCalibrationError  # noqa: E402
from giwbc.locomotion.simulation import Push, simulate_walk  # noqa: E402
from giwbc.locomotion.walker_config import WALKER_PRESETS, walker_config  # noqa: E402
from giwbc.plants import NOMINAL, available_variants  # noqa: E402
from giwbc.randomization.plant_distribution import RANDOM  # noqa: E402
from giwbc.robot import load  # noqa: E402
from giwbc.robot.mujoco_model import foot_sensor_names  # noqa: E402

WALK_COMMANDS = {"forward_0.3": (0.3, 0.0, 0.0), "forward_0.5": (0.5, 0.0, 0.0), "turn_0.3": (0.0, 0.0, 0.3)}
LOADED_N = 20.0  # a foot bearing more than this (touch sensor) counts as standing on the floor
COMMAND_START = 0.5
TRACKING_FROM = 2.0  # s after the command: per-tick tracking leaves out the start
PUSH_START = 2.0
SETTLE = 0.5  # s: the start (a seeded perturbation settling onto the floor) is left out of tilt and slip
PUSH_DURATION = 0.2

DEFINITIONS = {
    "falls": "runs ending with the base below 65 % of its standing height or tilted over 45 deg",
    "max_foot_tilt_deg": "largest angle between a loaded foot's sole normal and the vertical (touch > 20 N), over all ticks after 0.5 s of all runs",
    "max_foot_slip_mm": "largest horizontal travel of a loaded foot's sole centre within one stance, over all stances of all runs",
    "step_tracking_rms": "per-step base xy velocity (heading frame of the step's start) vs command, RMS over steps after the first two, then over non-falling runs, m/s",
    "tick_tracking_rms": "per-tick base xy velocity in the heading frame vs command from 2 s after the command, RMS over ticks of non-falling runs, m/s",
    "tick_yaw_rate_rms": "per-tick base yaw rate vs command, same ticks, rad/s",
    "push_success": "not fallen 3 s after the push ends; 95 % Wilson interval",
}

ENV_DEFINITIONS = {
    "conditions": "G1Walk-v0 in the policy's training conditions (estimated state, AHRS IMU, soft-limit ends); truth sampled at 50 Hz",
    "falls": "episodes ending early (a fall or a soft joint-limit end)",
    "estimator_tilt_error_deg": "max angle between the true and estimated base z axes after 0.5 s",
    "estimator_velocity_error_rms": "RMS of the base xy velocity error of the estimate (world frame), m/s",
    "estimator_height_error_max_m": "max |true - estimated base height|, m",
    "estimator_height_drift_max_m": "max |height error - its first sampled value| over the episode, m",
    "estimator_contact_agreement": "share of (sample, foot) pairs where the estimate's contact flag equals the touch sensor's load > 20 N",
    "estimator_false_stance": "share of (sample, foot) pairs taken as standing while carrying under 20 N",
    "estimator_missed_stance": "share of (sample, foot) pairs carrying over 20 N but taken as in swing",
    "push_directions": "seeded random (the environment's pushes), --directions pushes per seed",
    "calibration_failures": "episodes whose start-up IMU calibration never saw a standstill (counted as falls)",
    "paired": "--policy: walker alone vs policy on the same seeds and plant draws; successes (push: not fallen --judge-after s after the push "
              "ends; stand/walk: not fallen) with 95 % Wilson intervals, saved/lost = discordant pairs, exact two-sided McNemar p; per_plant: the same per drawn plant",
}


class Monitor:
    """Per-tick foot tilt and slip and heading-frame tracking, from MuJoCo's ground truth."""

    def __init__(self, description, command: tuple[float, float, float]) -> None:
        self.feet = [(c.link, foot_sensor_names(c.name)["touch"], np.asarray(c.center, float)) for c in description.contacts]
        self.command = np.asarray(command, float)
        self.anchor: dict[str, np.ndarray | None] = {link: None for link, _, _ in self.feet}
        self.max_tilt = 0.0
        self.max_slip = 0.0
        self.errors: list[np.ndarray] = []

    def __call__(self, robot, controller) -> None:
        t = robot.time()
        if t < SETTLE:
            return
        for link, touch, center in self.feet:
            position, rotation = robot.link_pose(link)
            if float(robot.sensor(touch)[0]) > LOADED_N:
                self.max_tilt = max(self.max_tilt, math.degrees(math.acos(min(1.0, max(-1.0, float(rotation[2, 2]))))))
                sole = (position + rotation @ center)[:2]
                anchor = self.anchor[link]
                if anchor is None:
                    self.anchor[link] = sole
                else:
                    self.max_slip = max(self.max_slip, float(np.linalg.norm(sole - anchor)))
            else:
                self.anchor[link] = None
        if t >= COMMAND_START + TRACKING_FROM:
            base = robot.base_state()
            yaw = math.atan2(base.rotation[1, 0], base.rotation[0, 0])
            c, s = math.cos(yaw), math.sin(yaw)
            v = base.linear_velocity
            self.errors.append(np.array([c * v[0] + s * v[1], -s * v[0] + c * v[1], base.angular_velocity[2]]) - self.command)


def _rms(values: list[float]) -> float | None:
    values = [v for v in values if math.isfinite(v)]
    return round(float(np.sqrt(np.mean(np.square(values)))), 4) if values else None


def run_cell(description, plant: str, command, seconds: float, seeds: list[int], config=None) -> dict:
    """Runs of one command on one plant: falls, tilt, slip, tracking."""
    falls, tilt, slip, step_rms, tick_xy, tick_yaw = 0, 0.0, 0.0, [], [], []
    for seed in seeds:
        monitor = Monitor(description, command)
        run = simulate_walk(description, command, seconds, command_start=COMMAND_START, seed=seed, config=config,
                            plant=None if plant == NOMINAL else plant, observe=monitor)
        falls += run.fell
        tilt, slip = max(tilt, monitor.max_tilt), max(slip, monitor.max_slip)
        if not run.fell:
            step_rms.append(run.tracking_rms)
            if monitor.errors:
                errors = np.array(monitor.errors)
                tick_xy.extend(np.linalg.norm(errors[:, :2], axis=1).tolist())
                tick_yaw.extend(errors[:, 2].tolist())
    return {"runs": len(seeds), "falls": falls, "max_foot_tilt_deg": round(tilt, 2), "max_foot_slip_mm": round(1000 * slip, 1),
            "step_tracking_rms": _rms(step_rms), "tick_tracking_rms": _rms(tick_xy), "tick_yaw_rate_rms": _rms(tick_yaw)}


def run_pushes(description, plant: str, force: float, directions: int, seeds: list[int], judge_after: float, config=None) -> dict:
    """Standing pushes, stepping allowed: success = not fallen ``judge_after`` s after the push ends."""
    successes, n, tilt, slip = 0, 0, 0.0, 0.0
    seconds = PUSH_START + PUSH_DURATION + judge_after
    for seed in seeds:
        for k in range(directions):
            push = Push(PUSH_START, force, 2 * math.pi * k / directions, PUSH_DURATION)
            monitor = Monitor(description, (0.0, 0.0, 0.0))
            run = simulate_walk(description, (0.0, 0.0, 0.0), seconds, pushes=(push,), command_start=None, seed=seed, config=config,
                                plant=None if plant == NOMINAL else plant, observe=monitor)
            successes += not run.fell
            n += 1
            tilt, slip = max(tilt, monitor.max_tilt), max(slip, monitor.max_slip)
    low, high = wilson_interval(successes, n)
    return {"pushes": n, "force_N": force, "successes": successes, "push_success": round(successes / n, 3) if n else None,
            "push_success_95ci": [round(low, 3), round(high, 3)], "max_foot_tilt_deg": round(tilt, 2), "max_foot_slip_mm": round(1000 * slip, 1)}


SHIPPED_WALK_POLICY = Path(__file__).resolve().parents[1] / "policies" / "g1_walk_residual.onnx"
AGENT_HZ = 50.0


def env_conditions(policy_path: str | None) -> dict:
    """gymnasium.make options of the estimator-in-the-loop runs: a policy's training conditions (its metadata)."""
    from giwbc.policy import OnnxPolicy

    kwargs = dict(OnnxPolicy(str(policy_path or SHIPPED_WALK_POLICY)).metadata["env_kwargs"])
    kwargs.pop("max_episode_steps", None)
    sim2real = dict(kwargs.get("sim2real") or {})
    sim2real["pushes"] = None
    kwargs["sim2real"] = sim2real
    return kwargs


class EnvMonitor(Monitor):
    """:class:`Monitor` at the agent rate, plus the estimator's errors against the truth."""

    def __init__(self, description, command) -> None:
        super().__init__(description, command)
        self.tilt_error = 0.0
        self.velocity_errors: list[float] = []
        self.height_error = 0.0
        self.height_drift = 0.0
        self._height_error0: float | None = None
        self.contact_pairs = np.zeros(3, dtype=int)  # agreeing, false stance, missed stance (sample, foot) pairs
        self.samples = 0
        self.calibration_failed = False
        self.plant: str | None = None  # the plant the episode drew (plant="random"), None otherwise

    def observe_env(self, env) -> None:
        runtime = env.unwrapped
        truth = runtime.engine_robot
        self(truth, None)
        estimated = getattr(runtime, "estimated", None)
        if estimated is None or truth.time() < SETTLE:
            return
        true_state, estimate = truth.base_state(), estimated.base_state()
        cosine = float(np.clip(true_state.rotation[:, 2] @ estimate.rotation[:, 2], -1.0, 1.0))
        self.tilt_error = max(self.tilt_error, math.degrees(math.acos(cosine)))
        self.velocity_errors.append(float(np.linalg.norm(true_state.linear_velocity[:2] - estimate.linear_velocity[:2])))
        height_error = float(estimate.position[2] - true_state.position[2])
        self.height_error = max(self.height_error, abs(height_error))
        if self._height_error0 is None:
            self._height_error0 = height_error
        self.height_drift = max(self.height_drift, abs(height_error - self._height_error0))
        latest = estimated.latest_estimate
        if latest is not None:
            loaded = np.array([float(truth.sensor(touch)[0]) > LOADED_N for _, touch, _ in self.feet])
            taken = np.asarray(latest.contacts, bool)
            self.contact_pairs += [int(np.sum(loaded == taken)), int(np.sum(taken & ~loaded)), int(np.sum(loaded & ~taken))]
            self.samples += len(loaded)


def run_env_episode(description, plant: str, command, seconds: float, seed: int, conditions: dict, policy,
                    push: tuple[float, float] | None = None):
    """One G1Walk episode at a fixed command (optionally one push ``(force, start)``): (fell, monitor, step rms)."""
    import gymnasium

    import giwbc.envs  # noqa: F401

    horizon = seconds + 1.0
    kwargs = dict(conditions)
    kwargs["commands"] = {"vx": [command[0]] * 2, "vy": [command[1]] * 2, "yaw_rate": [command[2]] * 2, "standing": 0.0,
                          "interval": [horizon, horizon], "horizon": horizon}
    if push is not None:
        force, start = push
        kwargs["sim2real"] = {**kwargs["sim2real"], "pushes": {"interval": [start, start], "duration": PUSH_DURATION,
                                                               "force": [force, force], "horizon": 2 * start + PUSH_DURATION}}
    if plant != NOMINAL:
        kwargs["plant"] = plant
    kwargs["max_episode_steps"] = int(round(seconds * AGENT_HZ))
    env = gymnasium.make("giwbc/G1Walk-v0", **kwargs)
    monitor = EnvMonitor(description, command)
    touchdowns = []
    try:
        try:
            observation, info = env.reset(seed=seed)
            monitor.plant = info.get("plant")
        except EstimatorCalibrationError:  # the start-up never saw a standstill on this plant: counted, not a crash
            monitor.calibration_failed = True
            monitor.plant = getattr(env.unwrapped, "plant", None)
            return True, monitor, math.nan
        zero = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
        walker = env.unwrapped.task.walker
        terminated = truncated = False
        steps = walker.state.steps
        while not (terminated or truncated):
            observation, _, terminated, truncated, _ = env.step(policy(observation) if policy is not None else zero)
            monitor.observe_env(env)
            if walker.state.steps != steps:
                steps = walker.state.steps
                base = env.unwrapped.engine_robot.base_state()
                touchdowns.append((env.unwrapped.engine_robot.time(), base.position[:2].copy(),
                                   math.atan2(base.rotation[1, 0], base.rotation[0, 0])))
    finally:
        env.close()
    rows = []
    for (t0, p0, y0), (t1, p1, y1) in zip(touchdowns[2:], touchdowns[3:]):
        c, s = math.cos(y0), math.sin(y0)
        dp = (p1 - p0) / (t1 - t0)
        rows.append([c * dp[0] + s * dp[1] - command[0], -s * dp[0] + c * dp[1] - command[1]])
    step_rms = float(np.sqrt(np.mean(np.sum(np.square(rows), axis=1)))) if rows else math.nan
    return bool(terminated), monitor, step_rms


def run_env_cell(description, plant: str, command, seconds: float, seeds: list[int], conditions: dict, policy) -> dict:
    falls, tilt, slip, step_rms, tick_xy, tick_yaw = 0, 0.0, 0.0, [], [], []
    est_tilt, est_velocity, est_height, est_drift, uncalibrated = 0.0, [], 0.0, 0.0, 0
    pairs, samples = np.zeros(3, dtype=int), 0
    outcomes = []
    for seed in seeds:
        fell, monitor, rms = run_env_episode(description, plant, command, seconds, seed, conditions, policy)
        outcomes.append((not fell, monitor.plant))
        falls += fell
        uncalibrated += monitor.calibration_failed
        tilt, slip = max(tilt, monitor.max_tilt), max(slip, monitor.max_slip)
        est_tilt, est_height = max(est_tilt, monitor.tilt_error), max(est_height, monitor.height_error)
        est_velocity.extend(monitor.velocity_errors)
        est_drift = max(est_drift, monitor.height_drift)
        pairs += monitor.contact_pairs
        samples += monitor.samples
        if not fell:
            step_rms.append(rms)
            if monitor.errors:
                errors = np.array(monitor.errors)
                tick_xy.extend(np.linalg.norm(errors[:, :2], axis=1).tolist())
                tick_yaw.extend(errors[:, 2].tolist())
    return {"runs": len(seeds), "falls": falls, "max_foot_tilt_deg": round(tilt, 2), "max_foot_slip_mm": round(1000 * slip, 1),
            "step_tracking_rms": _rms(step_rms), "tick_tracking_rms": _rms(tick_xy), "tick_yaw_rate_rms": _rms(tick_yaw),
            "estimator_tilt_error_deg": round(est_tilt, 3), "estimator_velocity_error_rms": _rms(est_velocity),
            "estimator_height_error_max_m": round(est_height, 4), "estimator_height_drift_max_m": round(est_drift, 4),
            **{name: (round(float(count) / samples, 4) if samples else None) for name, count in
               zip(("estimator_contact_agreement", "estimator_false_stance", "estimator_missed_stance"), pairs)},
            "calibration_failures": uncalibrated, "_outcomes": outcomes}


def run_env_pushes(description, plant: str, force: float, pushes: int, seeds: list[int], judge_after: float, conditions: dict,
                   policy) -> dict:
    successes, n, tilt, slip = 0, 0, 0.0, 0.0
    seconds = PUSH_START + PUSH_DURATION + judge_after
    outcomes = []
    for seed in seeds:
        for k in range(pushes):
            fell, monitor, _ = run_env_episode(description, plant, (0.0, 0.0, 0.0), seconds, seed * 100 + k, conditions, policy,
                                               push=(force, PUSH_START))
            outcomes.append((not fell, monitor.plant))
            successes += not fell
            n += 1
            tilt, slip = max(tilt, monitor.max_tilt), max(slip, monitor.max_slip)
    low, high = wilson_interval(successes, n)
    return {"pushes": n, "force_N": force, "successes": successes, "push_success": round(successes / n, 3) if n else None,
            "push_success_95ci": [round(low, 3), round(high, 3)], "max_foot_tilt_deg": round(tilt, 2), "max_foot_slip_mm": round(1000 * slip, 1),
            "_outcomes": outcomes}


def paired(walker: dict, acting: dict) -> dict:
    """Walker alone vs policy on the same episodes (same seeds, same plant draws): each arm's successes
    (push: not fallen 3 s after the push ends; stand/walk: not fallen) with 95 % Wilson intervals, the
    discordant pairs and the exact McNemar p-value, overall and per drawn plant."""
    a, b = walker.pop("_outcomes"), acting.pop("_outcomes")
    if [plant for _, plant in a] != [plant for _, plant in b]:
        raise RuntimeError("the arms ran on different plants: not paired")

    def figures(pairs: list) -> dict:
        n = len(pairs)
        wins = [sum(x for x, _ in pairs), sum(y for _, y in pairs)]
        saved, lost = sum(y and not x for x, y in pairs), sum(x and not y for x, y in pairs)
        return {"episodes": n, "walker_successes": wins[0], "walker_95ci": [round(v, 3) for v in wilson_interval(wins[0], n)],
                "policy_successes": wins[1], "policy_95ci": [round(v, 3) for v in wilson_interval(wins[1], n)],
                "saved": saved, "lost": lost, "mcnemar_exact_p": mcnemar_exact(saved, lost)}

    pairs = [(x, y) for (x, _), (y, _) in zip(a, b)]
    result = figures(pairs)
    plants = [plant for _, plant in a]
    if any(p is not None for p in plants):
        result["per_plant"] = {name: figures([pair for pair, p in zip(pairs, plants) if p == name]) for name in sorted(set(map(str, plants)))}
    return {"walker": walker, "policy": acting, "paired": result}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robot", default="g1")
    parser.add_argument("--plants", nargs="*", default=None, help="plants to run (default: nominal and every shipped variant)")
    parser.add_argument("--protocols", nargs="*", default=["stand", "walk", "push"], choices=["stand", "walk", "push"])
    parser.add_argument("--runs", type=int, default=10, help="runs per stand/walk cell (seeds seed_base..)")
    parser.add_argument("--push-runs", type=int, default=None, help="seeds per push direction (default: --runs)")
    parser.add_argument("--seed-base", type=int, default=20000, help="first seed (>= 20000: fresh, never tuned on)")
    parser.add_argument("--stand-seconds", type=float, default=10.0)
    parser.add_argument("--walk-seconds", type=float, default=20.0)
    parser.add_argument("--commands", nargs="*", default=list(WALK_COMMANDS), choices=list(WALK_COMMANDS))
    parser.add_argument("--push-force", type=float, default=100.0)
    parser.add_argument("--directions", type=int, default=8)
    parser.add_argument("--judge-after", type=float, default=3.0, help="s after the push ends when success is judged")
    parser.add_argument("--walker", default=None, choices=sorted(set(WALKER_PRESETS) - {"deployment"}),
                        help="a walker preset over the walker's own options (e.g. any_floor: a friction of 0.5); with --estimator / "
                             "--policy, over the policy's walker options")
    parser.add_argument("--walker-options", default=None, type=json.loads, metavar="JSON",
                        help='WalkerConfig fields over --walker (or the defaults), e.g. \'{"friction": 0.6}\'')
    parser.add_argument("--estimator", action="store_true", help="the walker on the estimated state (AHRS), through G1Walk-v0")
    parser.add_argument("--policy", default=None, help="a G1Walk policy .onnx: walker alone vs this policy, paired (same seeds, same plant "
                        "draws), in the policy's own training conditions (implies the env path)")
    args = parser.parse_args(argv)
    if RANDOM in (args.plants or []) and not (args.estimator or args.policy):
        parser.error("--plants random (a plant drawn per episode) runs through G1Walk-v0: add --estimator or --policy")
    env_mode = args.estimator or args.policy is not None
    conditions = env_conditions(args.policy) if env_mode else {}
    options = {**(WALKER_PRESETS[args.walker] if args.walker is not None else {}), **(args.walker_options or {})}
    walker = walker_config(options) if options else None
    if env_mode and options:
        own = conditions.get("walker")
        conditions["walker"] = {**(WALKER_PRESETS[own] if isinstance(own, str) else dict(own or {})), **options}

    def env_cell(run, *arguments) -> dict:  # one arm, or with --policy both arms paired
        if policy is None:
            row = run(*arguments, conditions, None)
            row.pop("_outcomes")
            return row
        return paired(run(*arguments, conditions, None), run(*arguments, conditions, policy))

    policy = None
    if args.policy is not None:
        from giwbc.policy import OnnxPolicy

        policy = OnnxPolicy(args.policy)
    description = load(args.robot)
    plants = args.plants or [NOMINAL, *available_variants(description)]
    seeds = [args.seed_base + i for i in range(args.runs)]
    push_seeds = [args.seed_base + i for i in range(args.push_runs if args.push_runs is not None else args.runs)]
    table: dict[str, dict] = {}
    started = time.perf_counter()
    for plant in plants:
        row: dict[str, dict] = {}
        if "stand" in args.protocols:
            row["stand"] = (env_cell(run_env_cell, description, plant, (0.0, 0.0, 0.0), args.stand_seconds, seeds) if env_mode
                            else run_cell(description, plant, (0.0, 0.0, 0.0), args.stand_seconds, seeds, walker))
        if "walk" in args.protocols:
            for name in args.commands:
                command = WALK_COMMANDS[name]
                row[f"walk_{name}"] = (env_cell(run_env_cell, description, plant, command, args.walk_seconds, seeds) if env_mode
                                       else run_cell(description, plant, command, args.walk_seconds, seeds, walker))
        if "push" in args.protocols:
            row["push"] = (env_cell(run_env_pushes, description, plant, args.push_force, args.directions, push_seeds, args.judge_after)
                           if env_mode else run_pushes(description, plant, args.push_force, args.directions, push_seeds, args.judge_after, walker))
        table[plant] = row
        print(f"{plant}: {json.dumps(row)}", file=sys.stderr, flush=True)
    mode = "policy" if args.policy else "estimator" if args.estimator else "truth"
    print(json.dumps({"benchmark": "robustness", "robot": args.robot, "mode": mode, "walker": args.walker, "walker_options": args.walker_options, "policy": args.policy, "seeds": [seeds[0], seeds[-1]] if seeds else [],
                      "stand_seconds": args.stand_seconds, "walk_seconds": args.walk_seconds, "commands": {k: WALK_COMMANDS[k] for k in args.commands},
                      "push": {"force_N": args.push_force, "duration_s": PUSH_DURATION, "start_s": PUSH_START, "directions": args.directions,
                               "judged_after_s": args.judge_after},
                      "definitions": {**DEFINITIONS, **(ENV_DEFINITIONS if env_mode else {})}, "plants": table, "wall_seconds": round(time.perf_counter() - started, 1)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
