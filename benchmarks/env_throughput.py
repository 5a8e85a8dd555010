"""Environment throughput on MuJoCo and PyBullet: steps/s, real-time factor, where the time goes, and
2-process scaling (one JSON object).

Each environment steps with zero actions (episodes reset on termination) in this process, pinned
to one thread; the share of wall time in the physics engine, in the controller (the WBC for
G1Balance) and in everything else comes from the runtime's own timers; ``real_time_factor_cpu``
divides the simulated time by the thread's CPU time instead of the wall time (the figure of a core
of its own, readable on a busy machine). Every case runs on both
engines (the ``*_pybullet`` entries: same task, same description, ``engine="pybullet"``).
G1Balance-v0 runs as registered (random pushes) and without pushes (quiet standing: the WBC's
warm-started best case). G1Walk-v0 runs as registered (random velocity commands, no pushes). Scaling: the same work (two identical jobs: same env, same seed, same
number of steps) run by 1 worker process in turn, then by 2 worker processes at once (fork);
identical jobs so that the two workers finish together and the ratio measures the machine, not
the spread of episode lengths between seeds. Repeated ``--scaling-repeats`` times (interleaved:
1, 2, 1, 2, ...); the median speed-up is reported with every repeat's.
"""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import multiprocessing as mp  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402

import giwbc.envs  # noqa: E402,F401

BASE_CASES: dict[str, tuple[str, dict[str, Any]]] = {
    "cartpole": (giwbc.envs.CARTPOLE_BALANCE, {}),
    "g1_balance_wbc": (giwbc.envs.G1_BALANCE, {"controller_rate": 500.0}),
    "g1_balance_wbc_no_pushes": (giwbc.envs.G1_BALANCE, {"controller_rate": 500.0, "sim2real": {"pushes": None}}),
    "g1_balance_pd": (giwbc.envs.G1_BALANCE, {"controller": "pd", "controller_rate": 50.0}),
    # walking on random commands (standing 15 % of the time), the walker + WBC at 500 Hz, policy 50 Hz
    "g1_walk": (giwbc.envs.G1_WALK, {"residuals": ["step"]}),
}
# Every case on MuJoCo (its name) and on PyBullet (its name + "_pybullet").
CASES: dict[str, tuple[str, dict[str, Any]]] = {
    **BASE_CASES,
    **{f"{name}_pybullet": (env_id, {**kwargs, "engine": "pybullet"}) for name, (env_id, kwargs) in BASE_CASES.items()},
}


def _run(env: Any, steps: int) -> float:
    """Step ``env`` ``steps`` times with zero actions; the wall time in seconds."""
    action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    started = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return time.perf_counter() - started


def measure(env_id: str, kwargs: dict[str, Any], steps: int) -> dict[str, Any]:
    env = gymnasium.make(env_id, **kwargs).unwrapped
    env.reset(seed=0)
    _run(env, max(1, steps // 10))  # warm up: caches, solver workspaces
    env.timings.clear()
    cpu_started = time.thread_time()
    wall = _run(env, steps)
    cpu = time.thread_time() - cpu_started
    timings, rates, engine = env.timings, env.rates, env.engine
    simulated = timings.physics_steps * rates.physics_dt
    env.close()
    return {
        "env": env_id,
        "engine": engine,
        "agent_hz": rates.agent,
        "controller_hz": rates.controller,
        "physics_hz": rates.physics,
        "steps": steps,
        "steps_per_s": steps / wall,
        "real_time_factor": simulated / wall,
        # Simulated time over this thread's CPU time: the real-time factor on a core of its own,
        # what the wall-clock figure reads on an idle machine (not lowered by other processes).
        "real_time_factor_cpu": simulated / cpu,
        "time_share": {
            "physics": timings.physics / wall,
            "controller": timings.controller / wall,
            "other": 1.0 - (timings.physics + timings.controller) / wall,
        },
        "us_per_physics_step": {
            "physics": 1e6 * timings.physics / timings.physics_steps,
            "controller": 1e6 * timings.controller / timings.physics_steps,
        },
    }


def _worker(env_id: str, kwargs: dict[str, Any], jobs: list[tuple[int, int]], barrier: Any, results: Any) -> None:
    """Run each ``(seed, steps)`` job on its own env, one after the other, after a common start."""
    envs = []
    for seed, _ in jobs:
        env = gymnasium.make(env_id, **kwargs).unwrapped
        env.reset(seed=seed)
        envs.append(env)
    barrier.wait()
    started = time.perf_counter()
    for env, (_, steps) in zip(envs, jobs):
        _run(env, steps)
    results.put(time.perf_counter() - started)


def scaling(env_id: str, kwargs: dict[str, Any], total_steps: int, workers: int, jobs: int = 2) -> float:
    """Throughput (steps/s) of ``workers`` processes sharing the same ``jobs`` seeded episodes' worth of steps.

    The work is identical whatever the number of workers: job ``i`` is seed ``i`` for ``total_steps / jobs``
    steps; one worker runs them in turn, two workers one each. Wall time from a common start (a barrier
    after every env is built) to the last worker's end.
    """
    context = mp.get_context("fork")
    barrier = context.Barrier(workers + 1)
    results = context.Queue()
    work = [(0, total_steps // jobs) for _ in range(jobs)]
    processes = [context.Process(target=_worker, args=(env_id, kwargs, work[index::workers], barrier, results))
                 for index in range(workers)]
    for process in processes:
        process.start()
    barrier.wait()
    started = time.perf_counter()
    for _ in processes:
        results.get()
    wall = time.perf_counter() - started
    for process in processes:
        process.join()
    return sum(steps for _, steps in work) / wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=2000, help="agent steps per measurement")
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    parser.add_argument("--scaling-case", default="g1_balance_wbc", choices=list(CASES))
    parser.add_argument("--scaling-steps", type=int, default=2000, help="total agent steps of the scaling test")
    parser.add_argument("--scaling-repeats", type=int, default=3, help="1-vs-2-process measurements (median reported)")
    args = parser.parse_args()

    result: dict[str, Any] = {
        "benchmark": "env_throughput",
        "machine": {"cpus": os.cpu_count(), "load_average_1min": os.getloadavg()[0], "python": platform.python_version()},
    }
    for name in args.cases:
        env_id, kwargs = CASES[name]
        result[name] = measure(env_id, kwargs, args.steps)
    result["pybullet_vs_mujoco"] = {
        name: {
            "mujoco_steps_per_s": result[name]["steps_per_s"],
            "pybullet_steps_per_s": result[f"{name}_pybullet"]["steps_per_s"],
            "pybullet_over_mujoco": result[f"{name}_pybullet"]["steps_per_s"] / result[name]["steps_per_s"],
        }
        for name in BASE_CASES
        if name in result and f"{name}_pybullet" in result
    }
    env_id, kwargs = CASES[args.scaling_case]
    pairs = [(scaling(env_id, kwargs, args.scaling_steps, 1), scaling(env_id, kwargs, args.scaling_steps, 2))
             for _ in range(max(1, args.scaling_repeats))]
    speedups = [two / one for one, two in pairs]
    result["scaling"] = {
        "case": args.scaling_case,
        "total_steps": args.scaling_steps,
        "steps_per_s_1_process": float(np.median([one for one, _ in pairs])),
        "steps_per_s_2_processes": float(np.median([two for _, two in pairs])),
        "speedup_2_over_1": float(np.median(speedups)),
        "speedups": speedups,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
