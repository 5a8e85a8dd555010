"""Time one whole-body-controller tick: Pinocchio pass, QP assembly, solve, total.

Usage: ``python benchmarks/wbc_tick.py --robot g1 [--solver proxsuite|osqp] [--seconds S] [--no-walk]``.
Prints ONE JSON object.

The states are realistic: a closed-loop MuJoCo run of the balance controller (standing, a ±3 cm
lateral CoM sway, a 60 N lateral push) is recorded first; the recorded ``(q, v, t)`` stream is then
replayed through a fresh controller and every tick is timed (``WbcResult.timings``: wall clock,
all Python overhead included), with every math library limited to one thread. ``in_loop`` gives the same tick measured inside the simulation loop while
recording (MuJoCo's step between ticks evicts caches, so it reads higher). Single-threaded and,
as the target is stated for one core, pinned to one CPU (the last one the process may use);
``--no-pin-cpu`` lets the scheduler move it (measured 3-5 % slower median on the 2-vCPU VM).

``walking`` (unless ``--no-walk``): the same for the walking controller
(:mod:`giwbc.locomotion.walker`) — a closed-loop MuJoCo walk at 0.3 m/s (seed 0) is recorded
(``(q, v, t, foot forces)``), then replayed through a fresh walking controller, which takes the
same decisions bit for bit; each WBC tick is classified as single support, double support, or
a contact switch (a tick whose contact activations differ from the previous tick's: the force
ramps of lift-off and touch-down, and the first tick of each phase). Its single-support median
is compared with the standing double-support median above (``single_over_standing``) and with
the walker's own double-support ticks (``single_over_double``: after the same between-tick
planning work, which leaves the caches colder than the standing replay's), all measured in this
one process, interleaved replays (``--repeat``); ``planning_us``: the walker's own work in those ticks (its update
minus the WBC tick). The same ticks split by who
answered (``guess_answered_us`` / ``backend_us``, ``backend_share``, the p99 with and without
the backend ticks), and ``backend_tick_parts_cpu_us``: the CPU time of each part of a backend
tick (the guess's failed KKT solves, proxsuite, the polish, the settle fallback), from one more
replay with those parts wrapped.

``standing_after_planning_us``: the standing replay once more, a walker's between-tick planning
(a separate walking controller stepping through the recorded walk, its WBC not run) before each
tick — the standing tick in the walking tick's context; ``single_over_standing_after_planning``
compares the single-support median with it (same process, interleaved).
"""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_variable] = "1"

import argparse  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import giwbc  # noqa: E402,F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
import numpy as np  # noqa: E402


def _pin_to_one_cpu() -> int | None:
    try:
        cpu = sorted(os.sched_getaffinity(0))[-1]
        os.sched_setaffinity(0, {cpu})
        return cpu
    except (AttributeError, OSError):
        return None


def _stats(values_s: list[float]) -> dict[str, float] | None:
    """Median, p99 and max in µs; None for no values (e.g. no tick needed the backend)."""
    if not len(values_s):
        return None
    us = np.asarray(values_s) * 1e6
    return {"median": round(float(np.median(us)), 1), "p99": round(float(np.percentile(us, 99)), 1), "max": round(float(us.max()), 1)}


def _stage_medians(timings: list) -> dict[str, float]:
    """Median µs of each part of ticks' ``WbcTimings`` (``result``: the rest of the tick)."""
    if not timings:
        return {}
    parts = {key: [getattr(t, key) for t in timings] for key in ("pinocchio", "build", "solve", "total")}
    parts["result"] = [t.total - t.pinocchio - t.build - t.solve for t in timings]
    return {key: round(float(np.median(values)) * 1e6, 1) for key, values in parts.items()}


def _guess_stats(solver) -> dict | None:
    guess = getattr(solver, "guess", None)
    if guess is None or not guess.tries:
        return None
    return {"tries": guess.tries, "hits": guess.hits, "hit_rate": round(guess.hits / guess.tries, 3)}


def _iteration_bound(solver) -> int | None:
    """The most proxsuite inner iterations one tick can run (outer budget × (inner + 1))."""
    if not hasattr(solver, "max_iter_in"):
        return None
    return solver.max_iter * (solver.max_iter_in + 1)


def _polish_stats(solver) -> dict | None:
    """How the backend's own solves ended: polished (exact, deterministic KKT answer) or not."""
    kkt = getattr(solver, "_kkt", None)
    if kkt is None:
        return None
    return {"polished": kkt.polished, "not_polished": kkt.polish_failures}


def record(description, solver: str, seconds: float, settings: dict) -> tuple[list, list]:
    """Closed-loop run with MuJoCo: stand, sway ±3 cm at 0.5 Hz, a 60 N lateral push."""
    from giwbc.control import make_balance_controller
    from giwbc.robot import MujocoRobot

    robot = MujocoRobot(description)
    controller = make_balance_controller(description, solver=solver, solver_settings=settings)
    states, in_loop = [], []
    dt = description.timestep
    omega = 2 * np.pi * 0.5
    for i in range(int(round(seconds / dt))):
        t = i * dt
        phase = t / seconds
        if 0.2 <= phase < 0.7:  # sway, eased in and out
            s = min(1.0, (phase - 0.2) / 0.1, (0.7 - phase) / 0.1)
            controller.set_com_offset([0.0, 0.03 * s * np.sin(omega * t), 0.0], [0.0, 0.03 * s * omega * np.cos(omega * t), 0.0])
        elif phase >= 0.7:
            controller.set_com_offset(np.zeros(3))
        push = 60.0 if 0.8 <= phase < 0.8 + 0.2 / seconds else 0.0
        robot.set_external_wrench(description.base_link, [0.0, push, 0.0])
        q, v = robot.generalized_state()
        result = controller.update(q, v, robot.time())
        states.append((q, v, robot.time(), controller.com_task.position_ref.copy()))
        in_loop.append(result.timings.total)
        robot.set_joint_torques(result.tau)
        robot.step()
    return states, in_loop


def record_walk(description, seconds: float, speed: float = 0.3, seed: int = 0) -> list:
    """Closed-loop MuJoCo walk at ``speed`` m/s from 0.5 s: the walker's inputs of every tick."""
    from giwbc.locomotion.simulation import perturbed_initial_state
    from giwbc.locomotion.walker import WalkingController
    from giwbc.robot import MujocoRobot
    from giwbc.robot.mujoco_model import foot_sensor_names

    robot = MujocoRobot(description)
    robot.reset(*perturbed_initial_state(robot, np.random.default_rng(seed)))
    walker = WalkingController(description)
    q, v = robot.generalized_state()
    walker.reset(q)
    touch = {side: foot_sensor_names(contact.name)["touch"] for side, contact in walker.contacts.items()}
    inputs = []
    dt = description.timestep
    for i in range(int(round(seconds / dt))):
        if i == int(round(0.5 / dt)):
            walker.set_command(speed, 0.0, 0.0)
        q, v = robot.generalized_state()
        forces = {side: float(robot.sensor(name)[0]) for side, name in touch.items()}
        inputs.append((q, v, robot.time(), forces, i == int(round(0.5 / dt))))
        result = walker.update(q, v, robot.time(), forces)
        robot.set_joint_torques(result.tau)
        robot.step()
    return inputs


def replay_walk(description, inputs: list, speed: float = 0.3) -> tuple[dict[str, list], int]:
    """Replay the recorded inputs through a fresh walking controller; tick times by kind (and,
    across kinds, ``guess``/``backend``: the ticks the active-set guess answered, the others;
    ``single_stages``/``double_stages``: those ticks' ``WbcTimings``)."""
    from giwbc.locomotion.walker import Phase, WalkingController

    walker = WalkingController(description)
    walker.reset(inputs[0][0])
    names = [contact.name for contact in walker.contacts.values()]
    kinds: dict[str, list] = {"single": [], "double": [], "switch": [], "guess": [], "backend": [], "single_stages": [], "double_stages": [],
                              "planning_single": [], "planning_double": []}
    previous = None
    clock = time.perf_counter
    failures = 0
    for i, (q, v, t, forces, start) in enumerate(inputs):
        if start:
            walker.set_command(speed, 0.0, 0.0)
        begin = clock()
        result = walker.update(q, v, t, forces)
        planning = clock() - begin - result.timings.total  # the walker's own work of the tick
        failures += not result.ok
        activations = tuple(walker.wbc.contact_activation(name) for name in names)
        phase = walker.state.phase
        if i >= 50:  # (the first ticks include the solver's initialisation)
            kinds["guess" if result.message == "active-set guess" else "backend"].append(result.timings.total)
            if activations != previous or (0.0 < min(activations) < 1.0):
                kinds["switch"].append(result.timings.total)
            elif phase is Phase.SINGLE:
                kinds["single"].append(result.timings.total)
                kinds["single_stages"].append(result.timings)
                kinds["planning_single"].append(planning)
            elif phase is Phase.DOUBLE or walker.state.steps:
                kinds["double"].append(result.timings.total)
                kinds["double_stages"].append(result.timings)
                kinds["planning_double"].append(planning)
        previous = activations
    return kinds, failures


def planning_context(description, inputs: list, speed: float = 0.3):
    """A callable running one tick of a walker's between-tick planning (measure, schedule, step
    adapter, swing and references) on the recorded walk's next inputs, its WBC not run: the work a
    walking WBC tick follows, put before a standing tick to compare the two in the same context."""
    from giwbc.locomotion.walker import WalkingController

    walker = WalkingController(description)
    walker.reset(inputs[0][0])
    walker.wbc.update = lambda q, v, t=None: None  # (planning only: the replayed walk's own WBC ticks are timed elsewhere)
    walker.set_command(speed, 0.0, 0.0)
    start = next((i for i, row in enumerate(inputs) if row[4]), 0)
    ticks = itertools.count()

    def plan() -> None:
        q, v, t, forces, _ = inputs[start + next(ticks) % (len(inputs) - start)]
        walker.update(q, v, t, forces)

    return plan


def profile_backend_ticks(description, inputs: list, speed: float = 0.3) -> dict:
    """CPU time (``time.thread_time``) of each part of the ticks the guess did not answer, in a
    separate replay with the parts wrapped (the wrappers' own cost is in the figures): the
    guess's failed KKT solves, proxsuite's update and solve (with its cold retry when one
    happens), the polish into the exact optimum, the settle fallback, and the whole walker tick.
    Medians and p90 over those ticks, µs."""
    from giwbc.locomotion.walker import WalkingController

    walker = WalkingController(description)
    walker.reset(inputs[0][0])
    solver = walker.wbc.solver
    kkt = getattr(solver, "_kkt", None)
    if kkt is None or getattr(solver, "guess", None) is None:
        return {}
    clock = time.thread_time
    parts: dict[str, float] = {}

    def wrap(owner, name: str, key: str) -> None:
        method = getattr(owner, name)

        def timed(*args, **kwargs):
            start = clock()
            try:
                return method(*args, **kwargs)
            finally:
                parts[key] = parts.get(key, 0.0) + clock() - start

        setattr(owner, name, timed)

    wrap(kkt, "try_solve", "guess")
    wrap(kkt, "polish", "polish")
    wrap(kkt, "settle", "settle")
    wrap(solver, "solve", "solver")
    rows: dict[str, list[float]] = {key: [] for key in ("guess", "proxsuite", "polish", "settle", "solver", "walker_tick")}
    inner: list[int] = []
    for i, (q, v, t, forces, start) in enumerate(inputs):
        if start:
            walker.set_command(speed, 0.0, 0.0)
        parts.clear()
        begin = clock()
        result = walker.update(q, v, t, forces)
        tick = clock() - begin
        if i < 50 or result.message == "active-set guess":
            continue
        for key in ("guess", "polish", "settle", "solver"):
            rows[key].append(parts.get(key, 0.0))
        rows["proxsuite"].append(parts.get("solver", 0.0) - sum(parts.get(key, 0.0) for key in ("guess", "polish", "settle")))
        rows["walker_tick"].append(tick)
        inner.append(result.iterations)
    if not inner:
        return {}
    report: dict = {key: {"median": round(float(np.median(values)) * 1e6, 1), "p90": round(float(np.percentile(values, 90)) * 1e6, 1)} for key, values in rows.items()}
    report["proxsuite_inner_iterations"] = {"median": float(np.median(inner)), "p90": float(np.percentile(inner, 90)), "max": int(max(inner))}
    report["ticks"] = len(inner)
    report["clock"] = "time.thread_time (CPU), parts wrapped"
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robot", default="g1")
    parser.add_argument("--solver", default="proxsuite", choices=["proxsuite", "osqp"])
    parser.add_argument("--seconds", type=float, default=6.0, help="simulated seconds recorded and replayed")
    parser.add_argument("--repeat", type=int, default=2, help="replays of the recording (ticks = repeat × recorded)")
    parser.add_argument("--no-pin-cpu", dest="pin_cpu", action="store_false",
                        help="do not pin the process to one CPU (pinning hurts if another busy process runs there)")
    parser.add_argument("--no-guess", action="store_true", help="no active-set guess: every tick runs the solver (and its polish)")
    parser.add_argument("--no-walk", dest="walk", action="store_false", help="skip the walking controller's single/double-support/switch ticks")
    parser.add_argument("--walk-seconds", type=float, default=6.0, help="simulated seconds of the recorded walk")
    args = parser.parse_args(argv)

    cpu = _pin_to_one_cpu() if args.pin_cpu else None
    import mujoco
    import pinocchio

    from giwbc.control import make_balance_controller
    from giwbc.control.qp.proxsuite_build import build_name, load_proxsuite
    from giwbc.robot import load

    description = load(args.robot)
    settings = {"active_set_guess": False} if args.no_guess else {}
    states, in_loop = record(description, args.solver, args.seconds, settings)

    walk_inputs = record_walk(description, args.walk_seconds) if args.walk else []
    walk_kinds: dict[str, list] = {"single": [], "double": [], "switch": [], "guess": [], "backend": [], "single_stages": [], "double_stages": [],
                                   "planning_single": [], "planning_double": []}
    walk_failures = 0

    controller = make_balance_controller(description, solver=args.solver, solver_settings=settings)
    timings, iterations, failures = [], [], 0
    after_planning: list[float] = []
    if walk_inputs:
        in_context = make_balance_controller(description, solver=args.solver, solver_settings=settings)
        plan = planning_context(description, walk_inputs)
    for _ in range(args.repeat):
        if walk_inputs:  # interleaved with the standing replays: the same machine state for both
            kinds, lost = replay_walk(description, walk_inputs)
            walk_failures += lost
            for key, values in kinds.items():
                walk_kinds[key] += values
            in_context.wbc.solver.reset()
            for i, (q, v, t, com_ref) in enumerate(states):
                plan()
                in_context.set_com_target(com_ref)
                result = in_context.update(q, v, t)
                if i >= 50:
                    after_planning.append(result.timings.total)
        controller.wbc.solver.reset()
        for q, v, t, com_ref in states:
            controller.set_com_target(com_ref)
            result = controller.update(q, v, t)
            timings.append(result.timings)
            iterations.append(result.iterations)
            failures += not result.ok
    warmup = min(50, len(timings) // 10)  # the first ticks include the solver's initialisation
    timings, iterations = timings[warmup:], iterations[warmup:]
    problem = controller.wbc.problem
    tick = {key: _stats([getattr(t, key) for t in timings]) for key in ("pinocchio", "build", "solve", "total")}
    other = [t.total - t.pinocchio - t.build - t.solve for t in timings]
    tick["result"] = _stats(other)
    report = {
        "robot": description.name,
        "solver": args.solver,
        "ticks": len(timings),
        "tick_us": tick,
        "in_loop_total_us": _stats(in_loop[warmup:]),
        "target_us": {"median": 150, "p99": 400},
        "problem": {
            "variables": problem.n,
            "equalities": problem.n_eq,
            "inequalities": problem.n_in,
            "variable_bounds": 0 if problem.lb is None else int(np.sum(np.isfinite(problem.lb) | np.isfinite(problem.ub))),
            "contacts": [c.name for c in controller.wbc.contacts],
            "contact_model": controller.config.contact_model,
            "tasks": [t.name for t in controller.wbc.tasks],
        },
        "iterations": {"median": float(np.median(iterations)), "p99": float(np.percentile(iterations, 99)), "max": int(max(iterations))},
        "failures": failures,
        "walking": None if not walk_inputs else {
            "single_support_us": _stats(walk_kinds["single"]),
            "double_support_us": _stats(walk_kinds["double"]),
            # Where a walking tick's time goes (medians, µs; tick_us above: the standing tick's).
            "stages_median_us": {kind: _stage_medians(walk_kinds[f"{kind}_stages"]) for kind in ("single", "double")},
            "contact_switch_us": _stats(walk_kinds["switch"]),
            # The walker's own work per tick (its update minus its WBC tick: measure, schedule,
            # step adapter, swing, references), in single and in double support.
            "planning_us": {"single": _stats(walk_kinds["planning_single"]), "double": _stats(walk_kinds["planning_double"])},
            # The ticks the guess answered and those that ran proxsuite + polish: the latter set
            # the walking tick's p99 (``p99_guess_only_us``: what it would be without them).
            "guess_answered_us": _stats(walk_kinds["guess"]),
            "backend_us": _stats(walk_kinds["backend"]),
            "backend_share": round(len(walk_kinds["backend"]) / max(1, len(walk_kinds["guess"]) + len(walk_kinds["backend"])), 4),
            "p99_all_us": round(float(np.percentile(walk_kinds["guess"] + walk_kinds["backend"], 99)) * 1e6, 1),
            "p99_guess_only_us": round(float(np.percentile(walk_kinds["guess"], 99)) * 1e6, 1),
            "backend_tick_parts_cpu_us": profile_backend_ticks(description, walk_inputs),
            "ticks": {key: len(values) for key, values in walk_kinds.items() if key in ("single", "double", "switch")},
            "single_over_standing": round(float(np.median(walk_kinds["single"]) / np.median([t.total for t in timings])), 3),
            # Against the walker's own double-support ticks (the same replays, the same planning
            # work before each tick): a WBC tick right after the walker's planning is ~4-6 µs
            # slower than the same tick repeated at once (cold caches), against ~1 µs for the
            # standing replay — this ratio leaves that context out.
            "single_over_double": round(float(np.median(walk_kinds["single"]) / np.median(walk_kinds["double"])), 3),
            # The standing replay with a walker's planning before each tick: the same context.
            "standing_after_planning_us": _stats(after_planning),
            "single_over_standing_after_planning": round(float(np.median(walk_kinds["single"]) / np.median(after_planning)), 3),
            "failures": walk_failures,
            "scenario": f"replay of a recorded closed-loop MuJoCo walk at 0.3 m/s from 0.5 s, {args.walk_seconds:g} s, seed 0; switch = activations changed or ramping",
        },
        "active_set_guess": _guess_stats(controller.wbc.solver),
        "backend_solves": _polish_stats(controller.wbc.solver),
        "iteration_bound": _iteration_bound(controller.wbc.solver),
        "scenario": "replay of a recorded closed-loop MuJoCo run at 500 Hz: stand, ±3 cm lateral CoM sway at 0.5 Hz, 60 N lateral push for 0.2 s",
        "threads": 1,
        "cpu": cpu,
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "versions": {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "pinocchio": pinocchio.__version__,
            "proxsuite": load_proxsuite().__version__,
            "proxsuite_build": build_name(load_proxsuite()),
            "mujoco": mujoco.__version__,
        },
        "clock": "time.perf_counter, wall clock",
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
