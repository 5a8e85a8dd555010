"""Environment throughput on MuJoCo and PyBullet: steps/s, real-time factor, where the time goes, and
2-process scaling (one JSON object).

Each environment steps with zero actions (episodes reset on termination) in this process, pinned
to one thread; the share of wall time in the physics engine, in the controller (the WBC for
G1Balance) and in everything else comes from the runtime's own timers; ``real_time_factor_cpu``
divides the simulated time by the thread's CPU time instead of the wall time (the figure of a core
of its own, readable on a busy machine). Every case runs on both
engines (the ``*_pybullet`` entries: same task, same description, ``engine="pybullet"``).
G1Balance-v0 runs as registered (random pushes) and without pushes (quiet standing: the WBC's
warm-started best case). G1Walk-v0 runs as registered (random velocity commands, no pushes).

Scaling (``--scaling-cases``, default G1Balance with the WBC and G1Walk): the same work (two
identical jobs: same env, same seed, same number of steps) run by 1 worker process in turn, then
by 2 worker processes at once (fork); identical jobs so that the two workers finish together and
the ratio measures the machine, not the spread of episode lengths between seeds. Each worker
builds its own environments before a common start (a barrier) and shares nothing with the other
while it steps (no lock, no pipe: one queue put at its end); the wall time runs from the common
start to the last worker's end. Repeated ``--scaling-repeats`` times (interleaved: 1, 2, 1, 2,
...); the median speed-up is reported with every repeat's, and with each worker's CPU time over
its wall time (``cpu_per_wall``: 1.0 when a worker had a core to itself; below 1 the machine was
busy with something else) and the load average before and after. On a shared machine the wall-time
ratio measures the share of the CPUs the benchmark got; ``cpu_efficiency_2_over_1`` (steps per
CPU-second of all workers, 2 processes over 1, median) says whether two processes slow each other
down (caches, memory bandwidth: < 1), and ``speedup_with_a_core_each`` = 2 x that is the ratio
on a machine with two free cores (derived, not measured: say which one you quote).
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

import giwbc  # noqa: E402,F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
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
    """Run each ``(seed, steps)`` job on its own env, one after the other, after a common start;
    put ``(wall, cpu)`` seconds (this process's CPU time) on ``results``."""
    envs = []
    for seed, _ in jobs:
        env = gymnasium.make(env_id, **kwargs).unwrapped
        env.reset(seed=seed)
        envs.append(env)
    barrier.wait()
    started, cpu = time.perf_counter(), time.process_time()
    for env, (_, steps) in zip(envs, jobs):
        _run(env, steps)
    results.put((time.perf_counter() - started, time.process_time() - cpu))


def scaling(env_id: str, kwargs: dict[str, Any], total_steps: int, workers: int, jobs: int = 2) -> tuple[float, float, float]:
    """Throughput (steps/s) of ``workers`` processes sharing the same ``jobs`` jobs, the workers'
    mean CPU time over wall time, and their steps per CPU-second.

    The work is identical whatever the number of workers: every job is seed 0 for ``total_steps / jobs``
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
    times = [results.get() for _ in processes]
    wall = time.perf_counter() - started
    for process in processes:
        process.join()
    steps = sum(steps for _, steps in work)
    return steps / wall, float(np.mean([cpu / own_wall for own_wall, cpu in times])), steps / sum(cpu for _, cpu in times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=2000, help="agent steps per measurement")
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    parser.add_argument("--scaling-cases", nargs="*", default=["g1_balance_wbc", "g1_walk"], choices=list(CASES))
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
    result["scaling"] = {name: measure_scaling(*CASES[name], args.scaling_steps, args.scaling_repeats) for name in args.scaling_cases}
    print(json.dumps(result))


def measure_scaling(env_id: str, kwargs: dict[str, Any], steps: int, repeats: int) -> dict[str, Any]:
    """1 vs 2 processes on the same work, ``repeats`` times interleaved (module docstring)."""
    load_before = os.getloadavg()[0]
    pairs = [(scaling(env_id, kwargs, steps, 1), scaling(env_id, kwargs, steps, 2)) for _ in range(max(1, repeats))]
    speedups = [two[0] / one[0] for one, two in pairs]
    efficiency = float(np.median([two[2] / one[2] for one, two in pairs]))
    return {
        "env": env_id,
        "total_steps": steps,
        "steps_per_s_1_process": float(np.median([one[0] for one, _ in pairs])),
        "steps_per_s_2_processes": float(np.median([two[0] for _, two in pairs])),
        "speedup_2_over_1": float(np.median(speedups)),
        "speedups": speedups,
        "cpu_per_wall_1_process": [one[1] for one, _ in pairs],
        "cpu_per_wall_2_processes": [two[1] for _, two in pairs],
        "steps_per_cpu_s_1_process": [one[2] for one, _ in pairs],
        "steps_per_cpu_s_2_processes": [two[2] for _, two in pairs],
        "cpu_efficiency_2_over_1": efficiency,
        "speedup_with_a_core_each": 2.0 * efficiency,
        "load_average_1min": {"before": load_before, "after": os.getloadavg()[0]},
    }


if __name__ == "__main__":
    main()
