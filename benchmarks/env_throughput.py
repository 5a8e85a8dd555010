"""Environment throughput: agent steps per CPU-second against a plain MuJoCo G1 env, and (on request)
steps/s on MuJoCo and PyBullet, where the time goes, and 2-process scaling (one JSON object).

Relative throughput (always; ``"relative"`` in the output): agent steps per CPU-second (this
process's thread time, so a busy machine does not lower it) of

* ``plain_g1``: a plain MuJoCo G1 env, what an mjlab-style env costs on CPU: joint PD in the
  actuators (the description's gains, position targets = default pose + 0.25 x action), ``mj_step``
  with ``nstep=10`` (500 Hz physics, 50 Hz agent), an observation (projected gravity, base twist,
  joint positions and velocities, last action), a reward and a fall check in numpy;
* ``g1_balance``: ``G1Balance-v0`` as registered; ``g1_walk``: ``G1Walk-v0`` as registered;
* ``g1_walk_policy``: ``G1Walk-v0`` with the shipped walking policy's training kwargs (read from
  ``policies/g1_walk_residual.onnx``: estimator in the loop, AHRS IMU model, pushes),

all stepped with zero actions (episodes reset on termination, resets counted), interleaved: each
of ``--rounds`` rounds runs every configuration for ``--seconds`` CPU-seconds in turn; the medians
over rounds and the median of the per-round ratios to ``plain_g1`` are reported. Each tree runs in
a worker process of its own (the same script; the envs built once, before the first round);
``--baseline DIR`` adds a second worker importing giwbc from another source tree (e.g. a
``git worktree`` of an older commit) and alternates the two workers round by round, so both are
measured under the same load; ``current_over_baseline`` divides their medians.

Instructions per agent step (``--instructions STEPS``, needs valgrind): each of the four
configurations in a process of its own under callgrind, ``STEPS`` zero-action steps counted after 20
(``instructions``; with ``--baseline``, both trees and ``current_over_baseline``). A count, not a
time, but one a busy machine does not change: on a loaded 2-vCPU VM the timed rounds above vary by
up to 30 %, too much to see a few per cent (``--rounds 0 --instructions 50 --baseline DIR``: ~10
minutes there).

Where the time goes (``--breakdown SECONDS``): the same configurations (but the plain env) stepped
in this process with the methods of each part wrapped (physics, sensor model, estimator, WBC,
walker planning, resets: ``BREAKDOWN_PARTS``), each part's exclusive share of a step's time and µs
per agent step (``breakdown``).

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
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
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


# --- relative throughput: steps per CPU-second against a plain MuJoCo G1 env -------------------------
RELATIVE = ("plain_g1", "g1_balance", "g1_walk", "g1_walk_policy")
SHIPPED_WALK_POLICY = "g1_walk_residual.onnx"


class PlainG1:
    """A plain MuJoCo G1 env (module doc): joint PD in the actuators, ``nstep=10``, numpy observation and reward."""

    def __init__(self, nstep: int = 10, action_scale: float = 0.25) -> None:
        import mujoco
        from giwbc.robot import load

        description = load("g1")
        self.mujoco, self.model = mujoco, description.build_mujoco()
        self.data = mujoco.MjData(self.model)
        model, n = self.model, self.model.nu
        joints = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, model.actuator_trnid[i, 0]) for i in range(n)]
        order = [list(description.joint_names).index(name) for name in joints]
        kp, kd = description.kp[order], description.kd[order]
        model.actuator_gaintype[:] = mujoco.mjtGain.mjGAIN_FIXED
        model.actuator_biastype[:] = mujoco.mjtBias.mjBIAS_AFFINE
        model.actuator_gainprm[:, 0] = kp
        model.actuator_biasprm[:, :3] = np.stack([np.zeros(n), -kp, -kd], axis=1)
        self.default = description.default_positions[order].copy()
        self.nstep, self.scale = nstep, action_scale
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (n,), np.float32)
        self.last_action = np.zeros(n)

    def reset(self, seed: int | None = None) -> np.ndarray:
        self.mujoco.mj_resetDataKeyframe(self.model, self.data, 0)
        self.last_action[:] = 0.0
        self.mujoco.mj_forward(self.model, self.data)
        return self._observe()

    def _observe(self) -> np.ndarray:
        data = self.data
        w, x, y, z = data.qpos[3:7]
        gravity = np.array([2 * (w * y - x * z), -2 * (w * x + y * z), -(w * w - x * x - y * y + z * z)])  # projected
        return np.concatenate([gravity, data.qvel[:6], data.qpos[7:] - self.default, data.qvel[6:], self.last_action])

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        data = self.data
        data.ctrl[:] = self.default + self.scale * action
        self.mujoco.mj_step(self.model, data, nstep=self.nstep)
        observation = self._observe()
        height = data.qpos[2]
        reward = float(np.exp(-((height - 0.78) / 0.1) ** 2) - 0.01 * np.sum(np.square(action - self.last_action))
                       - 1e-4 * np.sum(np.square(data.qvel[6:])))
        self.last_action[:] = action
        return observation, reward, bool(height < 0.5), False, {}


def relative_envs(names: tuple[str, ...] = RELATIVE) -> dict[str, Any]:
    """The configurations of the relative measurement (all four by default), reset with seed 0."""
    from giwbc.policy import OnnxPolicy

    def walk_policy() -> Any:
        policy = Path(giwbc.__file__).resolve().parents[1] / "policies" / SHIPPED_WALK_POLICY  # the source tree's
        return gymnasium.make(giwbc.envs.G1_WALK, **OnnxPolicy(policy).metadata["env_kwargs"]).unwrapped

    makers: dict[str, Any] = {
        "plain_g1": PlainG1,
        "g1_balance": lambda: gymnasium.make(giwbc.envs.G1_BALANCE).unwrapped,
        "g1_walk": lambda: gymnasium.make(giwbc.envs.G1_WALK).unwrapped,
        "g1_walk_policy": walk_policy,
    }
    envs = {name: makers[name]() for name in names}
    for env in envs.values():
        env.reset(seed=0)
    return envs


def _steps_per_cpu_second(env: Any, seconds: float) -> float:
    """Step ``env`` with zero actions (resetting on termination) for at least ``seconds`` of this
    thread's CPU time; its agent steps per CPU-second."""
    action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    steps, started = 0, time.thread_time()
    while True:
        for _ in range(10):
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        steps += 10
        spent = time.thread_time() - started
        if spent >= seconds:
            return steps / spent


def _worker_loop(seconds: float) -> None:
    """The worker's side: build the envs, warm them up, say ``ready``; then one JSON line of steps per
    CPU-second per configuration for every ``run`` read on stdin, until ``quit``."""
    envs = relative_envs()
    for env in envs.values():
        _steps_per_cpu_second(env, 0.2 * seconds)
    print(json.dumps({"ready": True, "giwbc": str(Path(giwbc.__file__).resolve().parent)}), flush=True)
    for line in sys.stdin:
        if line.strip() != "run":
            break
        print(json.dumps({name: _steps_per_cpu_second(env, seconds) for name, env in envs.items()}), flush=True)


class _Worker:
    """A worker process importing giwbc from ``tree`` (this script with ``--worker``)."""

    def __init__(self, tree: Path, seconds: float) -> None:
        environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
        self.process = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker", "--seconds", str(seconds)],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=environment, cwd=str(tree))
        self.hello = self._read()

    def _read(self) -> dict[str, Any]:
        assert self.process.stdout is not None
        line = self.process.stdout.readline()
        if not line:
            raise RuntimeError(f"benchmark worker exited with {self.process.wait()}")
        return json.loads(line)

    def run(self) -> dict[str, float]:
        assert self.process.stdin is not None
        self.process.stdin.write("run\n")
        self.process.stdin.flush()
        return self._read()

    def close(self) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write("quit\n")
        self.process.stdin.close()
        self.process.wait()


def relative(rounds: int, seconds: float, baseline: Path | None) -> dict[str, Any]:
    """Steps per CPU-second of every configuration in this tree (and ``baseline``'s), interleaved (module doc)."""
    trees = {"current": Path(__file__).resolve().parents[1]}
    if baseline is not None:
        trees["baseline"] = baseline.resolve()
    workers = {name: _Worker(tree, seconds) for name, tree in trees.items()}
    measured: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
    try:
        for _ in range(rounds):
            for name, worker in workers.items():
                measured[name].append(worker.run())
    finally:
        for worker in workers.values():
            worker.close()
    result: dict[str, Any] = {"rounds": rounds, "cpu_seconds_per_configuration_and_round": seconds,
                              "unit": "agent steps per CPU-second (zero actions, resets included)"}
    for name, runs in measured.items():
        result[name] = {
            "giwbc": workers[name].hello["giwbc"],
            "steps_per_cpu_s": {c: float(np.median([run[c] for run in runs])) for c in RELATIVE},
            "over_plain_g1": {c: float(np.median([run[c] / run["plain_g1"] for run in runs])) for c in RELATIVE},
            "rounds": {c: [round(run[c], 1) for run in runs] for c in RELATIVE},
        }
    if baseline is not None:
        result["current_over_baseline"] = {
            c: float(np.median([now[c] / then[c] for now, then in zip(measured["current"], measured["baseline"])])) for c in RELATIVE
        }
    return result


# --- instructions per agent step (valgrind's callgrind): a count a busy machine does not change ---------
INSTRUCTION_WARMUP = 20  # agent steps before the counted ones (caches, solver workspaces, compiled kernels loaded)


def _step_zero(env: Any, steps: int) -> None:
    action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()


def _count_worker(name: str, steps: int) -> None:
    """Inside callgrind started with ``--instr-atstart=no``: build configuration ``name``, step it
    :data:`INSTRUCTION_WARMUP` times, then count the instructions of ``steps`` more (instrumentation
    switched on and off around them by ``callgrind_control``)."""
    env = relative_envs((name,))[name]
    _step_zero(env, INSTRUCTION_WARMUP)
    subprocess.run(["callgrind_control", "--instr=on", str(os.getpid())], check=True, capture_output=True)
    _step_zero(env, steps)
    subprocess.run(["callgrind_control", "--instr=off", str(os.getpid())], check=True, capture_output=True)


def _count(tree: Path, name: str, steps: int, folder: Path) -> float:
    """User-space instructions per agent step of configuration ``name`` imported from ``tree``."""
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    command = ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={folder / 'callgrind.%p'}",
               sys.executable, str(Path(__file__).resolve()), "--count-worker", name, "--instructions", str(steps)]
    done = subprocess.run(command, capture_output=True, text=True, env=environment, cwd=str(tree))
    counted = [line for line in done.stderr.splitlines() if "Collected :" in line]
    if done.returncode != 0 or not counted:
        raise RuntimeError(f"callgrind run of {name} in {tree} failed ({done.returncode}): {done.stderr[-2000:]}")
    return int(counted[-1].split("Collected :")[1]) / steps


def instructions(steps: int, baseline: Path | None) -> dict[str, Any]:
    """Instructions per agent step of every configuration in this tree (and ``baseline``'s): each
    configuration in its own process under callgrind, zero actions from ``reset(seed=0)``, the
    steps after :data:`INSTRUCTION_WARMUP` counted. The same code on the same inputs executes the same
    instructions however loaded the machine is (to within Python's hash randomisation), so a change
    of a few per cent shows where the timed rounds' spread hides it; it counts work, not time (no
    cache misses, no instruction-level parallelism). Under callgrind a configuration runs ~50× slower:
    ~1-3 minutes each here."""
    if shutil.which("valgrind") is None or shutil.which("callgrind_control") is None:
        raise SystemExit("--instructions needs valgrind (apt-get install valgrind)")
    trees = {"current": Path(__file__).resolve().parents[1]}
    if baseline is not None:
        trees["baseline"] = baseline.resolve()
    result: dict[str, Any] = {"unit": "user-space instructions per agent step (callgrind)", "steps": steps, "warmup": INSTRUCTION_WARMUP}
    with tempfile.TemporaryDirectory() as folder:
        for tree_name, tree in trees.items():
            result[tree_name] = {name: _count(tree, name, steps, Path(folder)) for name in RELATIVE}
    if baseline is not None:
        result["current_over_baseline"] = {name: result["current"][name] / result["baseline"][name] for name in RELATIVE}
    return result


# --- where a step's CPU goes: exclusive time per part, from wrappers in this process ------------------
BREAKDOWN_PARTS = {  # part: (module, class, methods); the engine's physics first (innermost)
    "physics": ("giwbc.robot.mujoco_robot", "MujocoRobot", ("step",)),
    "sensor_model": ("giwbc.robot.noise", "SensorModel", ("record",)),
    "estimator": ("giwbc.estimation.estimator", "StateEstimator", ("update",)),
    "wbc": ("giwbc.control.wbc", "WholeBodyController", ("update",)),
    "walker_planning": ("giwbc.locomotion.walker", "WalkingController", ("step",)),
    "reset": ("giwbc.runtimes.simulated", "SimulatedRuntime", ("reset",)),
}


class _PartTimer:
    """Exclusive time per part: a part's time less that of the parts it calls (a stack of starts;
    ``time.perf_counter``, ~0.07 µs a read: this thread's CPU clock costs a system call, ~1 µs)."""

    def __init__(self) -> None:
        self.totals: dict[str, float] = {}
        self._stack: list[list] = []  # [part, start, time of the parts called inside]

    def wrap(self, part: str, method: Any) -> Any:
        import functools

        clock, stack, totals = time.perf_counter, self._stack, self.totals
        totals.setdefault(part, 0.0)

        @functools.wraps(method)
        def timed(*args: Any, **kwargs: Any) -> Any:
            frame = [part, clock(), 0.0]
            stack.append(frame)
            try:
                return method(*args, **kwargs)
            finally:
                stack.pop()
                spent = clock() - frame[1]
                totals[part] += spent - frame[2]
                if stack:
                    stack[-1][2] += spent

        return timed


def breakdown(seconds: float) -> dict[str, Any]:
    """Per configuration of the relative measurement (but the plain env), stepped for ``seconds``
    CPU-seconds: each part's share of a step's time (exclusive, ``BREAKDOWN_PARTS``; ``task_and_runtime``: the rest — the task's
    action, observation and reward, the runtime's loop, the walker's robot reads through the
    estimated robot's caches), and µs per agent step. The parts' methods are wrapped in this
    process only (class attributes, restored after), ~0.5 µs a call. Wall time: on a busy machine
    (``cpu_over_wall`` below 1) preemptions fall in the parts in proportion to their time, so read
    the shares; the µs per agent step are a quiet machine's only."""
    import importlib

    timer = _PartTimer()
    originals = []
    for part, (module, name, methods) in BREAKDOWN_PARTS.items():
        cls = getattr(importlib.import_module(module), name)
        for method in methods:
            original = cls.__dict__[method]
            originals.append((cls, method, original))
            setattr(cls, method, timer.wrap(part, original))
    try:
        envs = relative_envs()
        out: dict[str, Any] = {}
        for config, env in envs.items():
            if config == "plain_g1":
                continue
            _steps_per_cpu_second(env, 0.2 * seconds)  # warm up
            for part in timer.totals:
                timer.totals[part] = 0.0
            started, cpu_started, steps = time.perf_counter(), time.thread_time(), 0
            action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
            while time.thread_time() - cpu_started < seconds:
                for _ in range(10):
                    _, _, terminated, truncated, _ = env.step(action)
                    if terminated or truncated:
                        env.reset()
                steps += 10
            wall, cpu = time.perf_counter() - started, time.thread_time() - cpu_started
            parts = {part: value for part, value in timer.totals.items() if value > 0.0}
            parts["task_and_runtime"] = wall - sum(parts.values())
            out[config] = {
                "agent_steps": steps,
                "cpu_over_wall": round(cpu / wall, 3),
                "share": {part: round(value / wall, 4) for part, value in parts.items()},
                "us_per_agent_step": {part: round(1e6 * value / steps, 1) for part, value in parts.items()},
                "unit": "wall time (perf_counter), the wrappers' own cost included in the parts they wrap",
            }
        return out
    finally:
        for cls, method, original in originals:
            setattr(cls, method, original)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=5, help="interleaved rounds of the relative measurement")
    parser.add_argument("--seconds", type=float, default=1.0, help="CPU-seconds per configuration and round")
    parser.add_argument("--baseline", type=Path, default=None, help="another source tree to measure alongside (its giwbc/)")
    parser.add_argument("--breakdown", type=float, default=0.0, metavar="SECONDS",
                        help="also time each part of a step (physics, sensor model, estimator, WBC, walker, resets) for SECONDS per configuration")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--instructions", type=int, default=0, metavar="STEPS",
                        help="also count instructions per agent step over STEPS steps of each configuration (valgrind's callgrind; with --baseline, both trees)")
    parser.add_argument("--count-worker", choices=RELATIVE, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--steps", type=int, default=2000, help="agent steps per measurement of --cases")
    parser.add_argument("--cases", nargs="*", default=[], choices=list(CASES), help="absolute steps/s and time shares (e.g. all of them)")
    parser.add_argument("--scaling-cases", nargs="*", default=[], choices=list(CASES), help="1-vs-2-process scaling")
    parser.add_argument("--scaling-steps", type=int, default=2000, help="total agent steps of the scaling test")
    parser.add_argument("--scaling-repeats", type=int, default=3, help="1-vs-2-process measurements (median reported)")
    args = parser.parse_args()
    if args.worker:
        _worker_loop(args.seconds)
        return
    if args.count_worker is not None:
        _count_worker(args.count_worker, args.instructions)
        return

    result: dict[str, Any] = {
        "benchmark": "env_throughput",
        "machine": {"cpus": os.cpu_count(), "load_average_1min": os.getloadavg()[0], "python": platform.python_version()},
    }
    if args.rounds > 0:
        result["relative"] = relative(args.rounds, args.seconds, args.baseline)
    if args.instructions > 0:
        result["instructions"] = instructions(args.instructions, args.baseline)
    if args.breakdown > 0:
        result["breakdown"] = breakdown(args.breakdown)
    for name in args.cases:
        env_id, kwargs = CASES[name]
        result[name] = measure(env_id, kwargs, args.steps)
    comparison = {
        name: {
            "mujoco_steps_per_s": result[name]["steps_per_s"],
            "pybullet_steps_per_s": result[f"{name}_pybullet"]["steps_per_s"],
            "pybullet_over_mujoco": result[f"{name}_pybullet"]["steps_per_s"] / result[name]["steps_per_s"],
        }
        for name in BASE_CASES
        if name in result and f"{name}_pybullet" in result
    }
    if comparison:
        result["pybullet_vs_mujoco"] = comparison
    if args.scaling_cases:
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
