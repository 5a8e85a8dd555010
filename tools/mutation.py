"""Mutation testing of giwbc's core modules with mutmut 3, one module group at a time.

Why per group: mutmut runs, for each mutant, only the tests that reach the mutated function, but
it first runs the selected tests once to learn that mapping. A small, fast test selection per
group keeps that affordable on a 2-vCPU machine; the slow closed-loop tests stay out.

Each group runs in its own scratch copy of the repository (``.mutation/<group>/``, gitignored):
the source, the tests, the robot and policy files, and a generated ``pyproject.toml`` holding
that group's ``[tool.mutmut]`` settings. A group's results are kept there, so a later run
resumes (``--fresh`` starts over; ``--rerun-survivors`` tests the surviving mutants again after
tests were added). Each group stops at its time budget; unfinished mutants count as not run.

The report (default ``mutation-report.txt``, gitignored) gives killed / total per group, the
equivalent mutants excluded (listed with a reason in ``tests/mutation_equivalents.md``), and the
diff of every surviving mutant.

    python tools/mutation.py                       # every group, default budgets
    python tools/mutation.py safety protocols      # some groups
    python tools/mutation.py --budget-scale 0.5    # half the time
    python tools/mutation.py wbc --sample 200      # a seeded random sample of the mutants not run yet
"""

from __future__ import annotations

import argparse
import fnmatch
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import giwbc  # noqa: F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCRATCH = ROOT / ".mutation"
EQUIVALENTS = ROOT / "tests" / "mutation_equivalents.md"
COPIED = ("giwbc", "tests", "robots", "policies")
KILLED = {"killed", "timeout", "caught by type check", "segfault"}  # a crashed test run detected the mutant too


@dataclass(frozen=True)
class Group:
    """Modules mutated together and the fast tests that should kill their mutants."""

    name: str
    modules: tuple[str, ...]  # globs relative to the repository root
    tests: tuple[str, ...]  # pytest arguments selecting the tests
    budget_s: float  # wall-clock budget of the mutation run on 2 vCPUs
    functions: tuple[str, ...] = ()  # mutant-name globs: only these are run and scored (default: all)
    excluded: tuple[str, ...] = ()  # module globs left out of ``modules`` (mutmut's do_not_mutate)

    def selects(self, name: str) -> bool:
        return not self.functions or any(fnmatch.fnmatchcase(name, pattern) for pattern in self.functions)


# The parts of giwbc/control/ with a group of their own; the "wbc" group takes the rest.
CONTROL_PARTS = ("giwbc/control/qp/*", "giwbc/control/tasks.py", "giwbc/control/kinodynamics.py", "giwbc/control/balance.py")

GROUPS: tuple[Group, ...] = (
    Group("safety", ("giwbc/hal/safety.py",),
          ("tests/test_safety_supervisor.py", "tests/test_safety_faults.py",
           "tests/test_supervisor.py::test_supervisor_names_a_motor_out_of_motor_mode_bus_off_and_driver_bugs",
           "tests/test_supervisor.py::test_signal_watch_sees_a_signal_delivered_to_another_thread",
           "-k", "supervisor or signal_watch or safety_supervisor"), 600),
    Group("protocols", ("giwbc/hal/protocols/*",),
          ("tests/test_mit_protocol.py", "tests/test_protocol_details.py",
           "tests/test_frames.py::test_the_multibus_codec_equals_each_buses_protocol"), 1200),
    Group("estimator", ("giwbc/estimation/estimator.py", "giwbc/estimation/estimated_robot.py", "giwbc/estimation/orientation.py"),
          ("tests/test_estimator.py", "tests/test_estimator_truth.py", "tests/test_estimation_calibration.py", "tests/test_orientation_filter.py",
           "-k", "not 20_s and not push_run and not 60_N and not stands_through_pushes"), 900),
    Group("stepping", ("giwbc/runtimes/simulated.py", "giwbc/tasks/rates.py"), ("tests/test_tasks_runtimes.py", "tests/test_engines.py"), 900,
          ("giwbc.tasks.rates.*", "giwbc.runtimes.simulated.xǁSimulatedRuntimeǁ__init__*",
           "giwbc.runtimes.simulated.xǁSimulatedRuntimeǁreset*", "giwbc.runtimes.simulated.xǁSimulatedRuntimeǁstep*",
           "giwbc.runtimes.simulated.xǁSimulatedRuntimeǁ_observe*", "giwbc.runtimes.simulated.xǁSimulatedRuntimeǁ_pace*",
           "giwbc.runtimes.simulated.xǁSimulatedRuntimeǁtime*", "giwbc.runtimes.simulated.xǁSimulatedRuntimeǁ_info*",
           "giwbc.runtimes.simulated.xǁStepTimings*", "giwbc.runtimes.simulated.x_timestep*")),
    Group("scoring", ("giwbc/apps/evaluation.py", "giwbc/apps/sim_to_sim.py", "giwbc/apps/walk_evaluation.py",
                      "giwbc/locomotion/push_scoring.py", "giwbc/locomotion/tracking.py"),
          ("tests/test_push_scoring.py", "tests/test_tracking_per_tick.py",
           "tests/test_scoring.py", "tests/test_evaluation.py", "tests/test_sim_to_sim.py", "tests/test_walk_evaluation.py",
           "-k", "not training and not zero_policy_walks and not cached_arms"), 900,
          ("giwbc.apps.evaluation.x_run_chunk*", "giwbc.apps.evaluation.x_run_episodes*", "giwbc.apps.evaluation.xǁArmResultǁ*",
           "giwbc.apps.evaluation.x_velocity_tracking_rms*", "giwbc.apps.walk_evaluation.x_paired_tracking*",
           "giwbc.apps.walk_evaluation.x__bootstrap_mean*", "giwbc.apps.walk_evaluation.x_tracking_summary*",
           "giwbc.apps.walk_evaluation.x__finite*", "giwbc.apps.walk_evaluation.xǁWalkProtocolǁ*",
           "giwbc.apps.evaluation.xǁComparisonǁ*", "giwbc.apps.evaluation.x_wilson_interval*", "giwbc.apps.evaluation.x_mcnemar_exact*",
           "giwbc.apps.evaluation.xǁPushProtocolǁ*", "giwbc.apps.sim_to_sim.x_run_job*", "giwbc.apps.sim_to_sim.x_evaluate*",
           "giwbc.apps.sim_to_sim.xǁCellǁ*", "giwbc.apps.sim_to_sim.xǁPushSettingǁ*",
           "giwbc.locomotion.push_scoring.x_judge_push*", "giwbc.locomotion.push_scoring.x_fall_times_summary*",
           "giwbc.locomotion.tracking.x_heading_frame_velocity*", "giwbc.locomotion.tracking.x_per_tick_tracking*")),
    # control/, split so that every mutant runs within its budget: each part with the fast tests that
    # reach it (the closed-loop runs, marked slow, stay out). The globs are fnmatch patterns, where
    # "*" also matches "/": "wbc" takes every module of giwbc/control/ that no other part takes.
    Group("qp", ("giwbc/control/qp/*",),
          ("tests/test_control_qp.py", "tests/test_active_set_search.py", "tests/test_active_set_fixed.py", "tests/test_proxsuite_build.py",
           "tests/test_touchdown_tick.py::test_a_cone_closed_at_zero_declared_fixed_gives_the_optimum_of_the_undeclared_problem",
           "tests/test_wbc.py", "tests/test_wbc_bounded.py", "-m", "not slow"), 1500),
    Group("wbc", ("giwbc/control/*.py",),
          ("tests/test_wbc.py", "tests/test_wbc_mujoco_dynamics.py", "tests/test_wbc_reset.py", "tests/test_wbc_bounded.py",
           "tests/test_wbc_task_api.py", "tests/test_control_physics.py", "tests/test_contact_set.py", "-m", "not slow"), 2400,
          excluded=CONTROL_PARTS),
    Group("tasks", ("giwbc/control/tasks.py",),
          ("tests/test_control_tasks.py", "tests/test_wbc.py", "tests/test_wbc_task_api.py", "tests/test_control_physics.py", "-m", "not slow"), 1500),
    Group("kinodynamics", ("giwbc/control/kinodynamics.py",),
          ("tests/test_kinodynamics.py", "tests/test_analytic_dynamics.py", "tests/test_wbc_mujoco_dynamics.py",
           "tests/test_control_physics.py", "-m", "not slow"), 1200),
    Group("balance", ("giwbc/control/balance.py",),
          ("tests/test_control_balance.py", "tests/test_wbc.py", "tests/test_wbc_reset.py", "-m", "not slow"), 900),
)


def _toml_list(values: tuple[str, ...] | list[str]) -> str:
    return "[" + ", ".join(f'"{v}"' for v in values) + "]"


def prepare(group: Group, fresh: bool) -> Path:
    """The group's scratch copy of the repository, with its mutmut settings; mutmut's state kept
    unless ``fresh``."""
    work = SCRATCH / group.name
    if fresh and work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    for name in COPIED:
        target = work / name
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(ROOT / name, target, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    (work / "pyproject.toml").write_text(
        "[tool.mutmut]\n"
        'source_paths = ["giwbc/"]\n'
        f"only_mutate = {_toml_list(group.modules)}\n"
        f"do_not_mutate = {_toml_list(group.excluded)}\n"
        f"pytest_add_cli_args_test_selection = {_toml_list(group.tests)}\n"
        'pytest_add_cli_args = ["-p", "no:cacheprovider"]\n'
        'also_copy = ["robots/", "policies/"]\n'
        "timeout_multiplier = 5.0\n"
        "\n[tool.pytest.ini_options]\n"
        'testpaths = ["tests"]\n'
        'markers = ["slow: closed-loop simulations that take several seconds"]\n'
    )
    return work


def _mutmut(work: Path, args: list[str], budget_s: float | None, log: Path) -> int:
    """Run ``mutmut args`` in ``work``; past the budget, the whole process group is stopped."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": ""}
    env.pop("MUJOCO_GL", None)
    command = [sys.executable, "-m", "mutmut", *args]
    with log.open("a") as out:
        process = subprocess.Popen(command, cwd=work, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            return process.wait(timeout=budget_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGINT)  # mutmut saves its results on interrupt
            try:
                return process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                return process.wait()


def results(work: Path) -> dict[str, str]:
    """Mutant name -> status, from mutmut's saved state."""
    done = subprocess.run([sys.executable, "-m", "mutmut", "results", "--all", "true"], cwd=work, capture_output=True,
                          text=True, env={**os.environ, "PYTHONPATH": ""})
    found = {}
    for line in done.stdout.splitlines():
        match = re.match(r"\s+(\S+): (.+)$", line)
        if match:
            found[match.group(1)] = match.group(2).strip()
    return found


def equivalents() -> dict[str, str]:
    """Mutant name -> reason, from the table rows of tests/mutation_equivalents.md (``| `name` | reason |``)."""
    if not EQUIVALENTS.exists():
        return {}
    found = {}
    for line in EQUIVALENTS.read_text().splitlines():
        match = re.match(r"\|\s*`([^`]+)`\s*\|\s*(.+?)\s*\|\s*$", line)
        if match:
            found[match.group(1)] = match.group(2)
    return found


def diff(work: Path, name: str) -> str:
    done = subprocess.run([sys.executable, "-m", "mutmut", "show", name], cwd=work, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": ""})
    return done.stdout.strip()


def run_group(group: Group, args: argparse.Namespace) -> list[str]:
    """Run one group and return its report lines."""
    work = SCRATCH / group.name if args.report_only else prepare(group, args.fresh)
    log = work / "mutmut.log"
    budget = group.budget_s * args.budget_scale
    started = time.monotonic()
    names: list[str] = list(group.functions)
    if args.sample and not args.report_only:
        # A seeded random sample of the mutants not run yet: an unbiased estimate of the score
        # where the budget cannot run them all (mutmut itself runs the cheapest first).
        status = results(work)
        if not status:  # not generated yet: a filter that matches nothing stops mutmut after
            _mutmut(work, ["run", "--max-children", str(args.jobs), "giwbc.none_such"], budget, log)  # generation and stats
            status = results(work)
        pending = sorted(n for n, s in status.items() if s == "not checked" and group.selects(n))
        chosen = np.random.default_rng(args.seed).choice(len(pending), size=min(args.sample, len(pending)), replace=False)
        names = [pending[i] for i in sorted(chosen)]
        if not names:
            names = ["giwbc.none_such"]
    elif args.rerun_survivors:
        excluded = equivalents()
        names = [n for n, s in results(work).items() if s not in KILLED and s != "not checked" and n not in excluded
                 and group.selects(n) and (not args.only or any(fnmatch.fnmatchcase(n, pattern) for pattern in args.only))]
    if not args.report_only and (names or not (args.rerun_survivors or args.sample)):
        _mutmut(work, ["run", "--max-children", str(args.jobs), *names], budget, log)
    elapsed = time.monotonic() - started
    status = {n: s for n, s in results(work).items() if group.selects(n)}
    excluded = equivalents()
    counted = {n: s for n, s in status.items() if n not in excluded}
    killed = sum(s in KILLED for s in counted.values())
    not_run = sum(s == "not checked" for s in counted.values())
    survivors = sorted(n for n, s in counted.items() if s not in KILLED and s != "not checked")
    score = killed / max(1, len(counted) - not_run)
    lines = [
        f"== {group.name}: {', '.join(group.modules)}",
        f"   tests: {' '.join(group.tests)}",
        *([f"   functions: {' '.join(group.functions)}"] if group.functions else []),
        f"   killed {killed} / {len(counted) - not_run} run ({100 * score:.1f} %); {not_run} not run within the budget;"
        f" {len(status) - len(counted)} equivalent excluded; {elapsed:.0f} s",
    ]
    for name in survivors:
        lines.append(f"-- {name}: {counted[name]}")
        if not args.no_diffs:
            lines += ["   " + line for line in diff(work, name).splitlines()]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("groups", nargs="*", help=f"groups to run (default: all): {[g.name for g in GROUPS]}")
    parser.add_argument("--report", default=str(ROOT / "mutation-report.txt"))
    parser.add_argument("--budget-scale", type=float, default=1.0, help="multiplies every group's time budget")
    parser.add_argument("--jobs", type=int, default=2, help="mutants tested in parallel")
    parser.add_argument("--fresh", action="store_true", help="forget earlier results of these groups")
    parser.add_argument("--rerun-survivors", action="store_true", help="only test again the mutants that survived (equivalents left out)")
    parser.add_argument("--only", nargs="*", default=[], help="with --rerun-survivors: only mutants matching these globs")
    parser.add_argument("--sample", type=int, default=0, help="run only a seeded random sample of this many of the mutants not run yet")
    parser.add_argument("--seed", type=int, default=0, help="seed of --sample")
    parser.add_argument("--report-only", action="store_true", help="run nothing: report the groups' saved results")
    parser.add_argument("--no-diffs", action="store_true", help="list surviving mutants without their diffs")
    args = parser.parse_args(argv)
    known = {g.name: g for g in GROUPS}
    unknown = set(args.groups) - set(known)
    if unknown:
        parser.error(f"unknown groups {sorted(unknown)}; known: {list(known)}")
    chosen = [known[name] for name in args.groups] if args.groups else list(GROUPS)
    report = Path(args.report)
    lines = [f"mutmut over giwbc's core modules ({time.strftime('%Y-%m-%d %H:%M')}); score = killed / run, "
             "equivalent mutants excluded (tests/mutation_equivalents.md)"]
    for group in chosen:
        if args.report_only and not (SCRATCH / group.name / "mutants").exists():
            lines.append(f"== {group.name}: never run")
            continue
        lines += run_group(group, args)
        report.write_text("\n".join(lines) + "\n")
    print("\n".join(line for line in lines if line.startswith(("==", "   killed"))))
    print(f"report: {report}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
