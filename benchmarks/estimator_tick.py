"""Time one state-estimator tick (``StateEstimator.update``) in the shipped walking policy's configuration,
and (``--baseline DIR``) against another source tree in the same run (one JSON object).

A closed-loop rollout of ``G1Walk-v0`` with the shipped walking policy's training kwargs (estimator in
the loop with :data:`~giwbc.estimation.estimator.ANY_FEET`, AHRS IMU model, pushes) is recorded first
(``--seed``, ``--steps`` agent steps of seeded random actions in [-0.3, 0.3], the start-up calibration
included): every measurement and contact plan the estimator was given. The recorded stream is then
replayed through a fresh estimator of the same configuration, every ``update`` timed (wall clock,
``perf_counter``), in a worker process per source tree (this one, and ``--baseline``'s: e.g. a ``git
worktree`` of an older commit, importing its own giwbc), the trees alternated round by round
(``--rounds``), so both see the same load. Reported per tree: the median over rounds of each
round's median and p99 (µs), where a tick goes (``parts_us``: the leg kinematics' ``compute``, the
Kalman filter's ``predict`` + ``correct``, the rest of ``update``; medians per tick from one more
replay with those methods wrapped, ~0.3 µs a wrapper included), and with a baseline
``baseline_over_current`` (median of the per-round ratios of the medians) and how far the two trees'
estimates are apart over the whole stream (``q``, ``v``, contact forces, covariance: largest
absolute difference, and relative to the largest magnitude of each; contact flags: ticks that
differ). The replay is open loop (the same measurements for both trees), so the comparison is the
estimator's alone.

Usage: ``python benchmarks/estimator_tick.py [--baseline DIR] [--rounds 5] [--seed 3] [--steps 150]``.
"""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import giwbc  # noqa: E402,F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
import numpy as np  # noqa: E402

FIELDS = ("time", "quaternion", "angular_velocity", "linear_acceleration", "joint_positions", "joint_velocities",
          "joint_efforts", "plan", "has_plan")


def record(seed: int, steps: int, path: Path) -> Any:
    """Run the rollout (module doc) and save every estimator input to ``path`` (npz); returns the
    env's ``sim2real["estimator"]`` value (what the workers build their estimator from)."""
    import gymnasium

    import giwbc.envs
    from giwbc.policy import OnnxPolicy

    policy = Path(giwbc.__file__).resolve().parents[1] / "policies" / "g1_walk_residual.onnx"
    kwargs = dict(OnnxPolicy(policy).metadata["env_kwargs"])
    env = gymnasium.make(giwbc.envs.G1_WALK, **kwargs).unwrapped
    estimator = env.task.robot.estimator
    rows: dict[str, list] = {name: [] for name in FIELDS}
    original = estimator.update

    def recording(measurement: Any, contacts: Any = None) -> Any:
        imu = measurement.imu
        rows["time"].append(float(imu.time))
        rows["quaternion"].append(np.asarray(imu.quaternion, float))
        rows["angular_velocity"].append(np.asarray(imu.angular_velocity, float))
        rows["linear_acceleration"].append(np.asarray(imu.linear_acceleration, float))
        rows["joint_positions"].append(np.asarray(measurement.joint_positions, float))
        rows["joint_velocities"].append(np.asarray(measurement.joint_velocities, float))
        rows["joint_efforts"].append(np.asarray(measurement.joint_efforts, float))
        rows["has_plan"].append(contacts is not None)
        rows["plan"].append(np.zeros(2, bool) if contacts is None else np.asarray(contacts, bool))
        return original(measurement, contacts)

    estimator.update = recording  # this instance only
    env.reset(seed=seed)
    actions = np.random.default_rng(seed).uniform(-0.3, 0.3, (steps, *env.action_space.shape)).astype(env.action_space.dtype)
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            break
    np.savez(path, **{name: np.array(values) for name, values in rows.items()})
    return kwargs["sim2real"]["estimator"]


def _worker(stream_path: str, config: Any, estimates_path: str) -> None:
    """The worker's side (in the tree on its PYTHONPATH): replay the stream once per ``run`` line read
    on stdin, print one JSON line (median, p99 µs; ``parts`` on ``parts``); the first replay's
    estimates go to ``estimates_path``. ``config``: the env's ``sim2real["estimator"]`` value."""
    from giwbc.estimation.estimator import Measurement
    from giwbc.robot import load
    from giwbc.robot.interface import ImuReading
    from giwbc.runtimes.estimated import EstimatorInLoop

    data = np.load(stream_path)
    stream = [
        (Measurement(ImuReading(data["quaternion"][k], data["angular_velocity"][k], data["linear_acceleration"][k],
                                float(data["time"][k])),
                     data["joint_positions"][k], data["joint_velocities"][k], data["joint_efforts"][k]),
         data["plan"][k] if data["has_plan"][k] else None)
        for k in range(len(data["time"]))
    ]
    loop = EstimatorInLoop.from_value(config)
    assert loop is not None
    estimator = loop.estimator(load("g1"))
    clock = time.perf_counter

    def replay(keep: bool = False) -> tuple[np.ndarray, list]:
        estimator.reset()
        ticks, estimates = np.empty(len(stream)), []
        for k, (measurement, plan) in enumerate(stream):
            started = clock()
            estimate = estimator.update(measurement, plan)
            ticks[k] = clock() - started
            if keep:
                estimates.append(estimate)
        return ticks, estimates

    _, estimates = replay(keep=True)
    np.savez(estimates_path, q=np.array([e.q for e in estimates]), v=np.array([e.v for e in estimates]),
             forces=np.array([e.contact_forces for e in estimates]), covariance=np.array([e.covariance for e in estimates]),
             contacts=np.array([e.contacts for e in estimates]))
    print(json.dumps({"ready": True, "giwbc": str(Path(sys.modules["giwbc"].__file__).resolve().parent)}), flush=True)
    for line in sys.stdin:
        command = line.strip()
        if command == "run":
            ticks, _ = replay()
            print(json.dumps({"median_us": 1e6 * float(np.median(ticks)), "p99_us": 1e6 * float(np.percentile(ticks, 99))}),
                  flush=True)
        elif command == "parts":
            print(json.dumps(_parts(estimator, replay)), flush=True)
        else:
            break


def _parts(estimator: Any, replay: Any) -> dict[str, float]:
    """Median µs per tick of the kinematics, the Kalman filter and the rest, from a replay with the
    instance's methods wrapped."""
    spent = {"kinematics": 0.0, "kalman_filter": 0.0}
    clock = time.perf_counter

    def wrap(owner: Any, name: str, part: str) -> None:
        method = getattr(owner, name)

        def timed(*args: Any, **kwargs: Any) -> Any:
            started = clock()
            try:
                return method(*args, **kwargs)
            finally:
                spent[part] += clock() - started

        setattr(owner, name, timed)

    wrap(estimator.kinematics, "compute", "kinematics")
    wrap(estimator.filter, "predict", "kalman_filter")
    wrap(estimator.filter, "correct", "kalman_filter")
    rows: list[tuple[float, float, float]] = []
    estimator.reset()
    stream_ticks, _ = replay()  # warm
    estimator.reset()
    original_update = estimator.update

    def update(*args: Any) -> Any:
        before = dict(spent)
        started = clock()
        result = original_update(*args)
        total = clock() - started
        kinematics, kalman = spent["kinematics"] - before["kinematics"], spent["kalman_filter"] - before["kalman_filter"]
        rows.append((kinematics, kalman, total - kinematics - kalman))
        return result

    estimator.update = update
    replay()
    del estimator.update
    for owner, name in ((estimator.kinematics, "compute"), (estimator.filter, "predict"), (estimator.filter, "correct")):
        delattr(owner, name)
    values = np.median(np.array(rows), axis=0) * 1e6
    return {"kinematics": round(float(values[0]), 2), "kalman_filter": round(float(values[1]), 2), "rest": round(float(values[2]), 2)}


class _Worker:
    def __init__(self, tree: Path, stream: Path, config: Any, estimates: Path) -> None:
        environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
        command = [sys.executable, str(Path(__file__).resolve()), "--worker", str(stream), json.dumps(config), str(estimates)]
        self.process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=environment, cwd=str(tree))
        self.hello = self.ask(None)

    def ask(self, command: str | None) -> dict[str, Any]:
        assert self.process.stdin is not None and self.process.stdout is not None
        if command is not None:
            self.process.stdin.write(command + "\n")
            self.process.stdin.flush()
        line = self.process.stdout.readline()
        if not line:
            raise RuntimeError(f"benchmark worker exited with {self.process.wait()}")
        return json.loads(line)

    def close(self) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write("quit\n")
        self.process.stdin.close()
        self.process.wait()


def _difference(current: Path, baseline: Path) -> dict[str, Any]:
    now, then = np.load(current), np.load(baseline)
    out: dict[str, Any] = {}
    for name in ("q", "v", "forces", "covariance"):
        gap = float(np.max(np.abs(now[name] - then[name])))
        out[name] = {"max_abs": gap, "max_abs_over_max_magnitude": gap / float(np.max(np.abs(then[name])))}
    out["contact_flag_ticks_differing"] = int(np.sum(np.any(now["contacts"] != then["contacts"], axis=1)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", type=Path, default=None, help="another source tree to replay alongside (its giwbc/)")
    parser.add_argument("--rounds", type=int, default=5, help="replays per tree, alternated")
    parser.add_argument("--seed", type=int, default=3, help="the recorded rollout's seed")
    parser.add_argument("--steps", type=int, default=150, help="agent steps recorded (after the calibration)")
    parser.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        stream, config, estimates = args.worker
        _worker(stream, json.loads(config), estimates)
        return
    with tempfile.TemporaryDirectory() as folder:
        stream = Path(folder) / "stream.npz"
        config = record(args.seed, args.steps, stream)
        trees = {"current": Path(__file__).resolve().parents[1]}
        if args.baseline is not None:
            trees["baseline"] = args.baseline.resolve()
        workers = {name: _Worker(tree, stream, config, Path(folder) / f"{name}.npz") for name, tree in trees.items()}
        rounds: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
        parts: dict[str, dict[str, float]] = {}
        try:
            for _ in range(args.rounds):
                for name, worker in workers.items():
                    rounds[name].append(worker.ask("run"))
            for name, worker in workers.items():
                parts[name] = worker.ask("parts")
        finally:
            for worker in workers.values():
                worker.close()
        ticks = int(len(np.load(stream)["time"]))
        result: dict[str, Any] = {
            "benchmark": "estimator_tick",
            "machine": {"cpus": os.cpu_count(), "load_average_1min": os.getloadavg()[0], "python": platform.python_version()},
            "stream": {"seed": args.seed, "agent_steps": args.steps, "ticks": ticks, "configuration": "G1Walk-v0, shipped policy kwargs"},
            "rounds": args.rounds,
            "unit": "µs per StateEstimator.update (wall clock, replayed stream)",
        }
        for name in trees:
            result[name] = {
                "giwbc": workers[name].hello["giwbc"],
                "median_us": round(float(np.median([r["median_us"] for r in rounds[name]])), 2),
                "p99_us": round(float(np.median([r["p99_us"] for r in rounds[name]])), 2),
                "rounds_median_us": [round(r["median_us"], 2) for r in rounds[name]],
                "parts_us": parts[name],
            }
        if args.baseline is not None:
            result["baseline_over_current"] = round(float(np.median(
                [then["median_us"] / now["median_us"] for now, then in zip(rounds["current"], rounds["baseline"])])), 3)
            result["estimates_current_vs_baseline"] = _difference(Path(folder) / "current.npz", Path(folder) / "baseline.npz")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
