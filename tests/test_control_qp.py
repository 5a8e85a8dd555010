"""The QP backends against the optimality conditions, checked independently of any solver.

A random strictly convex QP with equalities, two-sided inequalities and variable bounds: every
backend's answer must be feasible and satisfy the KKT conditions, with multipliers found here by
a bounded least-squares fit (scipy), not read from the solver — and, the optimum of a strictly
convex QP being unique, all backends must agree.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from giwbc.control import (
    ComTask,
    ContactForceRegularization,
    FrameOrientationTask,
    OsqpSolver,
    PostureTask,
    ProxsuiteSolver,
    QpsolversSolver,
    QpStatus,
    WholeBodyController,
    available_solvers,
    foot_contacts,
    make_solver,
)
from giwbc.control.qp import ActiveSetGuess, QpProblem

BACKENDS = {
    "proxsuite": {"eps_abs": 1e-9, "max_iter": 100, "max_iter_in": 100},
    "osqp": {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 50000},
    "qpsolvers:osqp": {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 50000, "polishing": True},
}


def random_qp(rng: np.random.Generator, n: int = 8, n_eq: int = 2, n_in: int = 6, structure: int = 1) -> QpProblem:
    """A strictly convex QP whose unconstrained optimum lies outside the feasible set (so that
    inequalities and bounds bind), with a known feasible point."""
    root = rng.normal(size=(n, n))
    H = root @ root.T + 0.5 * np.eye(n)
    feasible = rng.uniform(-0.5, 0.5, n)
    A = rng.normal(size=(n_eq, n))
    C = rng.normal(size=(n_in, n))
    cx = C @ feasible
    l = cx - rng.uniform(0.05, 0.5, n_in)
    u = cx + rng.uniform(0.05, 0.5, n_in)
    if n_in >= 2:
        l[0] = -np.inf  # one-sided rows too
        u[1] = np.inf
    g = -H @ rng.normal(scale=3.0, size=n)
    return QpProblem(H=H, g=g, A=A, b=A @ feasible, C=C, l=l, u=u, lb=np.full(n, -1.0), ub=np.full(n, 1.0), structure=structure)


def kkt_residual(p: QpProblem, x: np.ndarray, active: float = 1e-6) -> float:
    """Smallest ``‖Hx + g + Aᵀy + Σ z_i c_i‖∞`` over multipliers with the signs the active rows
    allow (``z ≥ 0`` at an upper limit, ``≤ 0`` at a lower one, 0 for an inactive row)."""
    rows = [p.C, np.eye(p.n)]
    lower = np.concatenate([p.l, p.lb])
    upper = np.concatenate([p.u, p.ub])
    value = np.concatenate([p.C @ x, x])
    normals = np.vstack(rows)
    at_upper = value >= upper - active
    at_lower = value <= lower + active
    columns = [p.A.T, normals[at_upper].T, normals[at_lower].T]
    matrix = np.hstack(columns)
    low = np.concatenate([np.full(p.n_eq, -np.inf), np.zeros(at_upper.sum()), np.full(at_lower.sum(), -np.inf)])
    high = np.concatenate([np.full(p.n_eq, np.inf), np.full(at_upper.sum(), np.inf), np.zeros(at_lower.sum())])
    fit = lsq_linear(matrix, -(p.H @ x + p.g), bounds=(low, high), method="bvls", tol=1e-14)
    return float(np.max(np.abs(matrix @ fit.x + p.H @ x + p.g)))


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_every_backend_returns_the_kkt_point_of_a_random_qp(seed: int) -> None:
    rng = np.random.default_rng(seed)
    problem = random_qp(rng)
    answers = {}
    for name, settings in BACKENDS.items():
        solution = make_solver(name, **settings).solve(problem.copy())
        assert solution.status is QpStatus.SOLVED, (name, solution.message)
        x = solution.x
        assert problem.violation(x) < 1e-7, name
        assert kkt_residual(problem, x) < 1e-5 * max(1.0, np.abs(problem.g).max()), name
        answers[name] = x
    reference = answers["proxsuite"]
    for name, x in answers.items():
        np.testing.assert_allclose(x, reference, atol=1e-5, err_msg=name)
    # The problem binds something: otherwise the check above would not test the constraints.
    unconstrained = np.linalg.solve(problem.H, -problem.g)
    assert problem.violation(unconstrained) > 1e-2


def test_the_active_set_guess_solves_the_qp_from_the_active_set_it_learned() -> None:
    rng = np.random.default_rng(6)
    problem = random_qp(rng)
    reference = make_solver("proxsuite", **BACKENDS["proxsuite"]).solve(problem.copy()).x
    guess = ActiveSetGuess()
    x = guess.polish(problem, reference)
    assert x is not None
    np.testing.assert_allclose(x, reference, atol=1e-6)
    assert problem.violation(x) < 1e-9 and kkt_residual(problem, x) < 1e-8  # exact, not approximate
    before = guess.hits
    again = guess.try_solve(problem)  # the learned active set answers the same problem (unregularised)
    assert again is not None and guess.hits == before + 1
    np.testing.assert_allclose(again, x, atol=1e-10)


@pytest.mark.parametrize("solver", ["proxsuite", "osqp"])
def test_a_copy_of_the_controllers_problem_gets_the_same_answer_from_the_same_backend(g1, solver: str) -> None:
    """The controller lays ``A`` and ``C`` out in one buffer and the active-set guess reads them
    through one view; a copy of the problem (same sizes, separate arrays) handed to the same
    backend afterwards must be read as itself, not through that view past the end of its ``A``."""
    wbc = WholeBodyController(g1.build_pinocchio(), solver=solver, solver_settings=BACKENDS[solver], torque_limits=g1.effort_limits)
    for contact in foot_contacts(g1, mu=0.6):
        wbc.add_contact(contact)
    wbc.add_task(ComTask(weight=10.0, kp=100.0))
    wbc.add_task(FrameOrientationTask("pelvis", kp=100.0))
    wbc.add_task(PostureTask(reference=g1.default_positions, weight=0.05, kp=50.0))
    wbc.add_task(ContactForceRegularization(weight=1e-5))
    problem = wbc.build(g1.default_configuration(), np.zeros(35))
    original = wbc.solve()
    assert original.ok
    x = original.x.copy()
    copy = problem.copy()
    for _ in range(2):  # cold for the copy, then its warm path
        again = wbc.solve(copy)
        assert again.ok, again.message
        np.testing.assert_allclose(again.x, x, atol=1e-6)
    assert wbc.solve().ok  # and back to the controller's own problem


def shapes_of_qps(rng: np.random.Generator) -> list[QpProblem]:
    """Random QPs of several shapes: with and without bounds, inequalities, equalities; sparse
    patterns given for one (the entries outside them are zero)."""
    full = random_qp(rng, structure=11)
    no_bounds = random_qp(rng, structure=12)
    no_bounds.lb = no_bounds.ub = None
    no_bounds.l = no_bounds.l - 5.0  # a bounded problem without the box: keep it bounded
    no_inequalities = random_qp(rng, n=6, n_eq=2, n_in=0, structure=13)
    no_equalities = random_qp(rng, n=5, n_eq=0, n_in=4, structure=14)
    patterned = random_qp(rng, structure=15)
    mask = rng.uniform(size=patterned.C.shape) < 0.6
    patterned.C = np.where(mask, patterned.C, 0.0)
    patterned.AC_pattern = np.vstack([np.ones_like(patterned.A, dtype=bool), mask])
    patterned.H_pattern = np.ones_like(patterned.H, dtype=bool)
    for p in (full, no_bounds, no_inequalities, no_equalities, patterned):
        p.validate()
    return [full, no_bounds, no_inequalities, no_equalities, patterned]


@pytest.mark.parametrize(
    "name, settings",
    [
        ("proxsuite", BACKENDS["proxsuite"]),
        ("proxsuite", {**BACKENDS["proxsuite"], "active_set_guess": False, "polish": False, "deterministic": False}),
        ("proxsuite", {**BACKENDS["proxsuite"], "polish": False}),
        ("osqp", BACKENDS["osqp"]),
        ("osqp", {**BACKENDS["osqp"], "active_set_guess": False}),
        ("qpsolvers:osqp", BACKENDS["qpsolvers:osqp"]),
    ],
    ids=["proxsuite", "proxsuite-plain", "proxsuite-unpolished", "osqp", "osqp-plain", "qpsolvers"],
)
def test_one_backend_instance_solves_a_stream_of_qps_of_changing_shapes(name: str, settings: dict) -> None:
    """One backend object, problems of five shapes in turn and each one again with a moved
    gradient (its warm path): every answer feasible and a KKT point, checked independently."""
    rng = np.random.default_rng(8)
    backend = make_solver(name, **settings)
    for problem in shapes_of_qps(rng) * 2:
        for _ in range(2):
            solution = backend.solve(problem)
            assert solution.ok, (name, problem.structure, solution.message)
            x = solution.x
            assert x.shape == (problem.n,) and problem.violation(x) < 1e-6
            bounded = problem if problem.lb is not None else _with_infinite_bounds(problem)
            assert kkt_residual(bounded, x) < 1e-4 * max(1.0, np.abs(problem.g).max()), (name, problem.structure)
            assert type(solution.iterations) is int and isinstance(solution.solve_time, float) and solution.solve_time >= 0.0
            problem.g = problem.g + rng.normal(scale=0.5, size=problem.n)
            # and the limits moved in place (the same arrays: a backend's fast path must read them again)
            problem.b[...] += rng.normal(scale=0.01, size=problem.n_eq)
            problem.l[...] -= 0.05
            problem.u[...] += 0.05
            # and the matrices and the variable bounds, in place, within their sparsity patterns
            problem.H[...] += 0.1 * np.eye(problem.n)
            problem.A[...] *= 1.01
            problem.C[...] *= 0.99
            if problem.lb is not None:
                problem.lb[...] -= 0.02
                problem.ub[...] -= 0.02


def _with_infinite_bounds(p: QpProblem) -> QpProblem:
    q = p.copy()
    q.lb, q.ub = np.full(p.n, -np.inf), np.full(p.n, np.inf)
    return q


def test_solvers_by_name() -> None:
    assert isinstance(make_solver(), ProxsuiteSolver)
    assert isinstance(make_solver("ProxQP"), ProxsuiteSolver) and isinstance(make_solver("OSQP"), OsqpSolver)
    via = make_solver("qpsolvers:osqp")
    assert isinstance(via, QpsolversSolver) and via.name == "osqp"
    names = available_solvers()
    assert names[:2] == ["proxsuite", "osqp"] and "proxqp" not in names and len(set(names)) == len(names)
    with pytest.raises(ValueError, match=r"^unknown QP solver 'simplex'; available: \['proxsuite', 'osqp'"):
        make_solver("simplex")
    with pytest.raises(ValueError, match=r"^qpsolvers backend 'cplex' is not installed; available: "):
        QpsolversSolver("cplex")
    with pytest.raises(ValueError, match=r"^max_iter and max_iter_in must be >= 1, got 0, 10$"):
        ProxsuiteSolver(max_iter=0)
    with pytest.raises(ValueError, match=r"^max_iter and max_iter_in must be >= 1, got 10, 0$"):
        ProxsuiteSolver(max_iter_in=0)
    with pytest.raises(ValueError, match=r"^unknown proxsuite settings \['eps_absolute', 'verbosity'\]$"):
        ProxsuiteSolver(verbosity=True, eps_absolute=1e-3, check_duality_gap=True)
    # One outer and one inner iteration is a valid (if tiny) budget; a setting by name is used.
    tiny = ProxsuiteSolver(max_iter=1, max_iter_in=1, active_set_guess=False, polish=False, deterministic=False)
    assert tiny.solve(_box_problem([0.5, 0.5], [1.0, 1.0])).iterations <= 1 * (1 + 1)
    # a duality gap of 1e-300 cannot be met: proxsuite runs out of iterations (the setting is passed on)
    strict = make_solver("proxsuite", eps_abs=1e-9, check_duality_gap=True, eps_duality_gap_abs=1e-300, eps_duality_gap_rel=0.0,
                         active_set_guess=False, polish=False, deterministic=False)  # fmt: skip
    assert strict.solve(random_qp(np.random.default_rng(3))).status is QpStatus.MAX_ITER
    # with no absolute tolerance, a relative one is the only way to converge: it is passed on too
    relative = ProxsuiteSolver(eps_abs=0.0, eps_rel=1e-6, max_iter=100, max_iter_in=100, active_set_guess=False, polish=False, deterministic=False)
    assert relative.solve(random_qp(np.random.default_rng(3))).status is QpStatus.SOLVED


@pytest.mark.parametrize("name", ["proxsuite", "osqp", "qpsolvers:osqp"])
def test_an_infeasible_qp_fails_cleanly_and_the_backend_recovers(name: str) -> None:
    """x₀ = 1 and 2 ≤ x₀ ≤ 3: infeasible. NaN answer, a failure status, a message naming the
    backend; the next, feasible, problem is solved (no warm start from the failure)."""
    infeasible = QpProblem(H=np.eye(1), g=np.zeros(1), A=np.ones((1, 1)), b=np.array([1.0]), C=np.ones((1, 1)),
                           l=np.array([2.0]), u=np.array([3.0]), structure=21)  # fmt: skip
    backend = make_solver(name, **BACKENDS[name])
    solution = backend.solve(infeasible)
    assert not solution.ok and np.all(np.isnan(solution.x)) and solution.x.shape == (1,)
    assert solution.message.startswith(backend.name) and solution.solver == backend.name
    assert solution.solve_time >= 0.0
    feasible = QpProblem(H=np.eye(1), g=np.zeros(1), A=np.ones((1, 1)), b=np.array([2.5]), C=np.ones((1, 1)),
                         l=np.array([2.0]), u=np.array([3.0]), structure=21)  # fmt: skip
    np.testing.assert_allclose(backend.solve(feasible).x, [2.5], atol=1e-5)


def test_proxsuite_bounds_its_work_per_tick() -> None:
    """``max_iter`` outer iterations of at most ``max_iter_in`` inner ones each, cold retry
    included: the reported (inner) iterations never exceed ``max_iter · (max_iter_in + 1)``."""
    rng = np.random.default_rng(9)
    backend = make_solver("proxsuite", eps_abs=1e-12, max_iter=3, max_iter_in=4, active_set_guess=False, polish=False, deterministic=False)
    for _ in range(4):
        solution = backend.solve(random_qp(rng, n=20, n_eq=3, n_in=25, structure=31))
        assert solution.iterations <= 3 * (4 + 1)


def test_the_default_proxsuite_backend_solves_small_random_qps_cold_where_its_polish_fails() -> None:
    """1000 small strictly convex QPs (6–12 variables, 0–3 equalities, 2–11 two- or one-sided
    rows, bounds some of them infinite), each solved cold by a fresh default backend: every one
    is solved, to osqp's optimum at 1e-10. Some end with proxsuite reporting success at a point
    off by 1e-6–5e-4, where the rows within the polish's slack are not the optimum's active set
    and the polish fails (on 7 of them: without :meth:`ActiveSetGuess.recover`, all 7 were
    reported failed, or out of iterations); the recovery reaches the exact optimum from there."""
    failures, polish_failures = [], 0
    for seed in range(1000):
        rng = np.random.default_rng(seed)
        n, n_eq, n_in = int(rng.integers(6, 13)), int(rng.integers(0, 4)), int(rng.integers(2, 12))
        problem = random_qp(rng, n=n, n_eq=n_eq, n_in=n_in, structure=1)
        if rng.uniform() < 0.5:
            problem.lb[rng.uniform(size=n) < 0.3] = -np.inf
            problem.ub[rng.uniform(size=n) < 0.3] = np.inf
        reference = OsqpSolver(eps_abs=1e-10, eps_rel=1e-10, max_iter=200000).solve(problem.copy())
        assert reference.status is QpStatus.SOLVED, seed
        backend = ProxsuiteSolver()
        solution = backend.solve(problem.copy())
        polish_failures += backend._kkt.polish_failures
        if solution.status is not QpStatus.SOLVED or np.abs(solution.x - reference.x).max() > 1e-6:
            failures.append((seed, solution.status.value, solution.message))
    assert failures == []
    assert polish_failures > 5, polish_failures  # the fallback was needed, and found the optimum


def test_osqp_with_a_variable_in_no_constraint_and_the_guess_answering_a_repeated_problem() -> None:
    """min ½‖x‖² − (1, 2, 3)·x  s.t.  x₀ + x₁ = 1,  x₀ ≤ 0.3, with x₂ in no constraint (an empty
    column of OSQP's constraint matrix): the optimum is (0, 1, 3). Solved again, the active-set
    guess answers, with no OSQP iteration."""
    problem = QpProblem(H=np.eye(3), g=-np.array([1.0, 2.0, 3.0]), A=np.array([[1.0, 1.0, 0.0]]), b=np.ones(1),
                        C=np.array([[1.0, 0.0, 0.0]]), l=np.array([-np.inf]), u=np.array([0.3]), structure=41)  # fmt: skip
    backend = make_solver("osqp", **BACKENDS["osqp"])
    first = backend.solve(problem)
    np.testing.assert_allclose(first.x, [0.0, 1.0, 3.0], atol=1e-6)
    assert first.message == "" and first.iterations > 0
    again = backend.solve(problem)
    assert again.message == "active-set guess" and again.iterations == 0
    np.testing.assert_allclose(again.x, [0.0, 1.0, 3.0], atol=1e-9)


# --- the backends' contract: failures, reports, warm starts, in-place updates --------------------
def _box_problem(target: np.ndarray, upper: np.ndarray, structure: int = 51) -> QpProblem:
    """``min ½‖x − target‖²  s.t.  x ≤ upper`` row by row (no equality): the optimum is
    ``min(target, upper)``, the multiplier of row i ``max(target_i − upper_i, 0)``."""
    n = len(target)
    return QpProblem(H=np.eye(n), g=-np.asarray(target, dtype=float), A=np.zeros((0, n)), b=np.zeros(0), C=np.eye(n),
                     l=np.full(n, -np.inf), u=np.asarray(upper, dtype=float), structure=structure)  # fmt: skip


def _timed(backend, problem: QpProblem):
    import time  # (the caller's own clock: a backend's solve_time is part of the time it took)

    start = time.perf_counter()
    solution = backend.solve(problem)
    return solution, time.perf_counter() - start


ALL_BACKENDS = [
    ("proxsuite", {}),
    ("proxsuite", {"active_set_guess": False, "polish": False, "deterministic": False}),
    ("osqp", {}),
    ("osqp", {"active_set_guess": False}),
    ("qpsolvers:osqp", {"eps_abs": 1e-9, "eps_rel": 1e-9, "polishing": True}),
    ("qpsolvers:proxqp", {"eps_abs": 1e-9}),
]
ALL_IDS = ["proxsuite", "proxsuite-plain", "osqp", "osqp-plain", "qpsolvers-osqp", "qpsolvers-proxqp"]


@pytest.mark.parametrize("name, settings", ALL_BACKENDS, ids=ALL_IDS)
def test_a_malformed_problem_is_a_failed_solve_that_names_the_backend(name: str, settings: dict) -> None:
    """A gradient of the wrong length (the backend's own library rejects it), first on a cold
    backend, then on one warm for that structure: a FAILED solution, NaN of the problem's size,
    the backend's name and its error in the message, no iteration, a solve time within the
    caller's; the next good problem is solved."""
    import warnings

    backend = make_solver(name, **settings)
    good = _box_problem([2.0, -1.0, 0.5], [1.0, 1.0, 1.0])
    for warm in (False, True):
        if warm:
            assert backend.solve(good).ok
        bad = good.copy()
        bad.g = np.zeros(5)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            solution, elapsed = _timed(backend, bad)
        assert solution.status is QpStatus.FAILED and not solution.ok
        assert solution.x.shape == (3,) and np.all(np.isnan(solution.x))
        assert solution.solver == backend.name and solution.message.startswith(f"{backend.name} error: ") and len(solution.message) > len(backend.name) + 8
        assert solution.iterations == 0 and 0.0 < solution.solve_time <= elapsed
        again = backend.solve(good)
        assert again.ok and again.solver == backend.name
        np.testing.assert_allclose(again.x, [1.0, -1.0, 0.5], atol=1e-6)


@pytest.mark.parametrize("name, settings", ALL_BACKENDS, ids=ALL_IDS)
def test_a_solved_problem_reports_its_backend_and_a_solve_time_within_the_callers(name: str, settings: dict) -> None:
    """Solved twice (the second time through each backend's warm path — the active-set guess
    where there is one): the optimum, SOLVED, the backend's name, a message saying which path
    answered, and a solve time in (0, the caller's elapsed time]."""
    backend = make_solver(name, **settings)
    problem = _box_problem([2.0, -1.0, 0.5], [1.0, 1.0, 1.0])
    guessing = getattr(backend, "guess", None) is not None
    for attempt in range(2):
        solution, elapsed = _timed(backend, problem)
        assert solution.status is QpStatus.SOLVED and solution.solver == backend.name
        np.testing.assert_allclose(solution.x, [1.0, -1.0, 0.5], atol=1e-6)
        assert 0.0 < solution.solve_time <= elapsed
        by_guess = attempt == 1 and guessing
        assert solution.message == ("active-set guess" if by_guess else "")
        if by_guess:
            assert solution.iterations == 0
            np.testing.assert_array_equal(solution.rows, problem.C @ solution.x)  # [A; C] x, the torques' source
        elif name.startswith("qpsolvers"):
            assert solution.iterations == 0  # (the one-shot path reports none)
        elif name == "osqp":
            assert solution.iterations > 0  # (proxsuite may solve this one in its initial factorisation: 0)
        if name == "proxsuite" and not settings:  # polished: [A; C] x computed on the way
            np.testing.assert_allclose(solution.rows[: problem.n_in], problem.C @ solution.x, atol=1e-12)


@pytest.mark.parametrize("name", ["proxsuite", "osqp"])
def test_the_guess_starts_from_the_active_set_the_backend_found(name: str) -> None:
    """The backend's answer teaches the guess its active set, bound sides included (x₀ at its
    upper limit with multiplier 0.5, x₂ at a lower limit with multiplier 2): the same problem
    again is answered by the guess in a single KKT solve, with no correction step."""
    settings = {**BACKENDS["proxsuite"], "polish": False, "deterministic": False} if name == "proxsuite" else {}
    backend = make_solver(name, **settings)
    problem = _box_problem([1.5, 0.2, -3.0], [1.0, 1.0, 1.0])
    problem.l[2] = -1.0
    first = backend.solve(problem)
    np.testing.assert_allclose(first.x, [1.0, 0.2, -1.0], atol=1e-5)
    backend.guess.steps = 1  # no correction allowed: the learned set must be right as it is
    again = backend.solve(problem)
    assert again.message == "active-set guess", again.message
    np.testing.assert_allclose(again.x, [1.0, 0.2, -1.0], atol=1e-12)


def test_settle_returns_the_kkt_point_of_the_rows_tight_at_a_point_when_it_is_feasible() -> None:
    """``settle``: the rows within ``slack`` (default 1e-5) of a bound at the given point become
    equalities; their KKT point is returned when it satisfies every row to ``feasibility``
    (default 1e-6), computed without regularisation when the rows are independent (exact) and
    with it when they are not (a duplicated row)."""
    inf = np.inf
    # min ½‖x − (1e4, 0)‖², x₀ ≤ 1, x₁ ≤ 0.5; at (1 − 1e-7, 0) only x₀ ≤ 1 is tight: the answer
    # is (1, 0), exactly (a regularised solve would be off by 1e-12 · λ = 1e-8).
    p = QpProblem(H=np.eye(2), g=np.array([-1e4, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.eye(2),
                  l=np.array([-inf, -inf]), u=np.array([1.0, 0.5]), structure=61)  # fmt: skip
    x = ActiveSetGuess().settle(p, np.array([1.0 - 1e-7, 0.0]))
    assert x is not None and abs(x[0] - 1.0) < 1e-12 and abs(x[1]) < 1e-12
    # The same row twice: a singular KKT system, settled by the regularised solve.
    twice = QpProblem(H=np.eye(2), g=np.array([-1e4, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.array([[1.0, 0.0], [1.0, 0.0]]),
                      l=np.array([-inf, -inf]), u=np.array([1.0, 1.0]), structure=62)  # fmt: skip
    x = ActiveSetGuess().settle(twice, np.array([1.0 - 1e-7, 0.0]))
    assert x is not None and abs(x[0] - 1.0) < 1e-6 and twice.violation(x) <= 1e-6
    # x₀ + x₁ ≤ 0.999 is not tight at (1 − 1e-7, −0.01) but the KKT point (1, 0) violates it by
    # 1e-3: refused at the default feasibility, accepted at 1e-2.
    p.C = np.array([[1.0, 0.0], [1.0, 1.0]])
    p.u = np.array([1.0, 0.999])
    point = np.array([1.0 - 1e-7, -0.01])
    assert ActiveSetGuess().settle(p, point) is None
    x = ActiveSetGuess().settle(p, point, feasibility=1e-2)
    assert x is not None and abs(x[0] - 1.0) < 1e-12 and abs(x[1]) < 1e-12


def _controller_layout(p: QpProblem) -> QpProblem:
    """``p`` with ``A`` and ``C`` views of one buffer and ``l``, ``u`` views of another, as the
    controller lays them out (the guess then reads them through views spanning both)."""
    rows = np.vstack([p.A, p.C])
    limits = np.concatenate([p.l, p.u])
    ne, ni = p.n_eq, p.n_in
    return QpProblem(H=p.H.copy(), g=p.g.copy(), A=rows[:ne], b=p.b.copy(), C=rows[ne:], l=limits[:ni], u=limits[ni:], structure=p.structure)


@pytest.mark.parametrize("layout", ["controller", "separate", "bounded"])
def test_the_guess_reads_each_problem_as_itself_whatever_its_layout_and_in_place_changes(layout: str) -> None:
    """One guess, two problems of the same sizes and different data used in turn, each changed
    in place between solves (limits, rows, gradient) the way the controller refills its buffers:
    every answer the guess gives is the optimum of the problem as it is now (checked against an
    accurate proxsuite solve), never one read from stale or foreign arrays."""
    rng = np.random.default_rng(12)
    reference = make_solver("proxsuite", **BACKENDS["proxsuite"], active_set_guess=False, polish=False, deterministic=False)

    def made(seed_rng: np.random.Generator) -> QpProblem:
        p = random_qp(seed_rng, n=6, n_eq=2, n_in=5, structure=71)
        if layout == "bounded":
            return p
        p.lb = p.ub = None
        p.l, p.u = p.l - 0.3, p.u + 0.3
        return _controller_layout(p) if layout == "controller" else p

    problems = [made(rng), made(rng)]
    guess = ActiveSetGuess()
    answered = 0
    for round_ in range(3):
        for p in problems:
            optimum = reference.solve(p.copy()).x
            polished = guess.polish(p, optimum)
            assert polished is not None
            np.testing.assert_allclose(polished, optimum, atol=1e-6)
            again = guess.try_solve(p)  # the polished active set, the same problem: answered
            assert again is not None
            np.testing.assert_allclose(again, polished, atol=1e-10)
            # in place, small: the same active set, a new optimum that the guess must find
            p.g[...] += rng.normal(scale=1e-3, size=p.n)
            p.b[...] += 1e-3
            p.l[...] -= 1e-3 * (round_ + 1)
            p.u[...] += 1e-3 * (round_ + 1)
            p.A[...] *= 1.001
            p.C[...] *= 0.999
            moved = guess.try_solve(p)
            assert moved is not None
            np.testing.assert_allclose(moved, reference.solve(p.copy()).x, atol=1e-6)
            assert p.violation(moved) < 1e-9 and kkt_residual(_with_infinite_bounds(p) if p.lb is None else p, moved) < 1e-7
            answered += 1
    assert answered == 6


def test_a_qp_problem_copies_validates_and_measures_its_violations() -> None:
    rng = np.random.default_rng(13)
    p = shapes_of_qps(rng)[4]  # with patterns and bounds
    copy = p.copy()
    for name in ("H", "g", "A", "b", "C", "l", "u", "lb", "ub", "H_pattern", "AC_pattern"):
        original, copied = getattr(p, name), getattr(copy, name)
        np.testing.assert_array_equal(copied, original, err_msg=name)
        assert copied is not original and not np.shares_memory(copied, original), name
    assert copy.structure == p.structure
    # Variable bounds alone: 0.3 below a lower bound, then 0.2 above an upper one.
    box = QpProblem(H=np.eye(2), g=np.zeros(2), A=np.zeros((0, 2)), b=np.zeros(0), C=np.zeros((0, 2)), l=np.zeros(0), u=np.zeros(0),
                    lb=np.array([-1.0, -1.0]), ub=np.array([1.0, 1.0]))  # fmt: skip
    assert box.violation(np.array([-1.3, 0.0])) == pytest.approx(0.3)
    assert box.violation(np.array([0.0, 1.2])) == pytest.approx(0.2)
    assert box.violation(np.array([0.5, -0.5])) == 0.0
    box.validate()
    box.lb = np.zeros(3)
    with pytest.raises(ValueError, match=r"^QP lb has shape \(3,\), expected \(2,\)$"):
        box.validate()
    box.lb, box.ub = np.zeros(2), None
    with pytest.raises(ValueError, match=r"^QP ub has shape None, expected \(2,\)$"):
        box.validate()


def test_the_qpsolvers_path_warm_starts_from_its_previous_answer_and_maps_infinite_bounds() -> None:
    """At a loose tolerance without polishing, OSQP's answer depends on where it starts: the same
    problem solved again from the previous answer comes closer to the optimum (a cold start
    would repeat the first answer bit for bit). Infinite variable bounds reach qpsolvers as
    ±1e20 (no bound), and a backend that checks its start (proxqp) takes no start of another
    size."""
    import warnings

    p = random_qp(np.random.default_rng(3))
    optimum = make_solver("proxsuite", **BACKENDS["proxsuite"]).solve(p.copy()).x
    loose = make_solver("qpsolvers:osqp", eps_abs=1e-3, eps_rel=1e-3, polishing=False, max_iter=50000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        first, second = loose.solve(p).x, loose.solve(p).x
        assert not np.array_equal(first, second)
        assert np.abs(second - optimum).max() < np.abs(first - optimum).max()
        # lb = (−inf, …): free below, the optimum unchanged where those bounds were not active
        free = p.copy()
        free.lb[optimum > -0.999] = -np.inf
        free.ub[optimum < 0.999] = np.inf
        x = make_solver("qpsolvers:osqp", **BACKENDS["qpsolvers:osqp"]).solve(free).x
        np.testing.assert_allclose(x, optimum, atol=1e-5)
        infeasible = QpProblem(H=np.eye(1), g=np.zeros(1), A=np.ones((1, 1)), b=np.array([1.0]), C=np.ones((1, 1)),
                               l=np.array([2.0]), u=np.array([3.0]), structure=21)  # fmt: skip
        failed = make_solver("qpsolvers:osqp").solve(infeasible)
        assert failed.status is QpStatus.FAILED and failed.message == "osqp: no solution found" and np.all(np.isnan(failed.x))
        proxqp = make_solver("qpsolvers:proxqp", eps_abs=1e-9)
        for problem in shapes_of_qps(np.random.default_rng(8)):
            solution = proxqp.solve(problem)
            assert solution.ok, solution.message
            assert problem.violation(solution.x) < 1e-6


def test_osqp_settings_silence_accuracy_and_warm_start(capfd) -> None:
    """The OSQP backend prints nothing; its default answer is exact (polished: KKT to 1e-10);
    unpolished it is still accurate to its default 1e-6 tolerances; without the guess the same
    problem is re-solved warm (fewer iterations), never through the guess; a time limit it
    cannot meet is a FAILED solve and an infeasible problem PRIMAL_INFEASIBLE, with the
    iterations it ran."""
    p = random_qp(np.random.default_rng(4))
    exact = make_solver("osqp").solve(p)
    assert exact.ok and p.violation(exact.x) < 1e-10 and kkt_residual(p, exact.x) < 1e-10
    rough = make_solver("osqp", polishing=False).solve(p)
    assert rough.ok and p.violation(rough.x) < 1e-5 and kkt_residual(p, rough.x) < 1e-4
    plain = make_solver("osqp", active_set_guess=False)
    runs = [plain.solve(p) for _ in range(3)]
    assert all(run.message == "" for run in runs) and runs[1].iterations < runs[0].iterations
    slow = make_solver("osqp", time_limit=1e-9, active_set_guess=False).solve(random_qp(np.random.default_rng(5), n=30, n_eq=3, n_in=40))
    assert slow.status is QpStatus.FAILED and slow.message == "osqp: run time limit reached"
    infeasible = QpProblem(H=np.eye(1), g=np.zeros(1), A=np.ones((1, 1)), b=np.array([1.0]), C=np.ones((1, 1)),
                           l=np.array([2.0]), u=np.array([3.0]), structure=21)  # fmt: skip
    for settings in ({}, {"active_set_guess": False}):
        failed = make_solver("osqp", **settings).solve(infeasible)
        assert failed.status is QpStatus.PRIMAL_INFEASIBLE and failed.message == "osqp: primal infeasible"
        assert type(failed.iterations) is int and failed.iterations > 0
    captured = capfd.readouterr()
    assert captured.out == "" and captured.err == ""


def test_osqp_with_a_sparsity_pattern_whose_last_variable_is_in_no_constraint() -> None:
    """An empty last column in the constraint pattern (the last variable in no row, no bounds):
    the optimum is still found, the free variable at its unconstrained optimum."""
    problem = QpProblem(H=np.eye(3), g=-np.array([1.0, 2.0, 3.0]), A=np.array([[1.0, 1.0, 0.0]]), b=np.ones(1),
                        C=np.array([[1.0, 0.0, 0.0]]), l=np.array([-np.inf]), u=np.array([0.3]), structure=42,
                        AC_pattern=np.array([[True, True, False], [True, False, False]]), H_pattern=np.eye(3, dtype=bool))  # fmt: skip
    solution = make_solver("osqp", **BACKENDS["osqp"]).solve(problem)
    assert solution.ok, solution.message
    np.testing.assert_allclose(solution.x, [0.0, 1.0, 3.0], atol=1e-6)


def test_proxsuite_flags_on_a_qp_with_a_direction_of_zero_curvature() -> None:
    """min ½x₀² − x₀ s.t. x₀ ≤ 0.5, with x₁ in no constraint and no cost: optimal for any x₁,
    no KKT system is regular. By default (polish, deterministic) that is a FAILED solve, never
    an arbitrary point: NaN, the reason in the message, the iterations proxsuite ran. With
    ``polish=False`` or ``deterministic=False`` proxsuite's own solution is returned."""
    def problem() -> QpProblem:
        return QpProblem(H=np.diag([1.0, 0.0]), g=np.array([-1.0, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.array([[1.0, 0.0]]),
                         l=np.array([-np.inf]), u=np.array([0.5]), structure=81)  # fmt: skip

    for settings in ({}, {"active_set_guess": False}):
        backend = make_solver("proxsuite", **settings)
        failed, elapsed = _timed(backend, problem())
        assert failed.status is QpStatus.FAILED and np.all(np.isnan(failed.x)) and failed.x.shape == (2,)
        assert failed.message == "proxsuite: solved, but no KKT point near its iterate is feasible"
        assert type(failed.iterations) is int and failed.iterations > 0 and 0.0 < failed.solve_time <= elapsed
    for settings in ({"polish": False}, {"deterministic": False}, {"polish": False, "deterministic": False}):
        solved = make_solver("proxsuite", **settings).solve(problem())
        assert solved.status is QpStatus.SOLVED and abs(solved.x[0] - 0.5) < 1e-5, settings
        assert solved.rows is None or np.allclose(solved.rows[:1], solved.x[:1])
    # Warm from a regular problem of the same structure: the warm solve's answer fails, the cold
    # retry's too; the tick reports the iterations of both.
    backend = make_solver("proxsuite")
    regular = problem()
    regular.H = np.eye(2)
    assert backend.solve(regular).ok
    cold = make_solver("proxsuite").solve(problem())
    failed = backend.solve(problem())
    assert failed.status is QpStatus.FAILED and failed.message == cold.message
    assert failed.iterations >= cold.iterations > 0


def test_the_backends_print_nothing(capfd) -> None:
    """Nor do they warn (OSQP warns when its solve is not told whether to raise)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for name, settings in ALL_BACKENDS[:4]:
            assert make_solver(name, **settings).solve(random_qp(np.random.default_rng(14))).ok
    captured = capfd.readouterr()
    assert captured.out == "" and captured.err == "" and [str(w.message) for w in caught] == []


def test_the_guess_counts_its_work_and_reads_equality_rows_given_as_two_sided_limits() -> None:
    """``tries``/``hits`` count :meth:`try_solve` calls and answers, ``polished``/``polish_failures``
    the polishes; a row with ``l = u`` (an equality written as an inequality) takes a multiplier
    of either sign: with no correction step allowed, the guess accepts its polished set whether
    the row holds x₀ up or down. The unregularised KKT solve is exact; a duplicated row is
    solved regularised."""
    inf = np.inf
    for target in (0.0, 1.0):  # the row holds x₀ up, then down
        # min ½‖x − (target, 1, 0)‖²  s.t.  x₁ + x₂ = 1 (an equality), 0.5 ≤ x₀ ≤ 0.5
        p = QpProblem(H=np.eye(3), g=-np.array([target, 1.0, 0.0]), A=np.array([[0.0, 1.0, 1.0]]), b=np.ones(1),
                      C=np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), l=np.array([0.5, -inf]), u=np.array([0.5, 2.0]), structure=91)  # fmt: skip
        optimum = np.array([0.5, 1.0, 0.0])
        guess = ActiveSetGuess(steps=1, polish_steps=1)
        x = guess.polish(p, optimum)
        assert x is not None, target
        np.testing.assert_allclose(x, optimum, atol=1e-9)
        again = guess.try_solve(p)
        assert again is not None and np.abs(again - optimum).max() < 1e-14
        assert (guess.tries, guess.hits, guess.polished, guess.polish_failures) == (1, 1, 1, 0)
    singular = QpProblem(H=np.diag([1.0, 0.0]), g=np.array([-1.0, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.array([[1.0, 0.0]]),
                         l=np.array([-inf]), u=np.array([0.5]), structure=92)  # fmt: skip
    guess = ActiveSetGuess()
    assert guess.polish(singular, np.array([0.5, 0.0])) is None and guess.try_solve(singular) is None
    assert (guess.tries, guess.hits, guess.polished, guess.polish_failures) == (1, 0, 0, 1)
    # From an empty active set: x₀ ≤ 1 added, solved without regularisation (exact, with λ = 1e4 − 1).
    far = QpProblem(H=np.eye(2), g=np.array([-1e4, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.eye(2),
                    l=np.array([-inf, -inf]), u=np.array([1.0, 0.5]), structure=93)  # fmt: skip
    x = ActiveSetGuess().try_solve(far)
    assert x is not None and abs(x[0] - 1.0) < 1e-12 and abs(x[1]) < 1e-12
    far.g, far.l = np.array([1e4, 0.0]), np.array([-1.0, -inf])  # and a lower limit, x₀ ≥ −1
    x = ActiveSetGuess().try_solve(far)
    assert x is not None and abs(x[0] + 1.0) < 1e-12 and abs(x[1]) < 1e-12
    # The same row twice: singular, solved again regularised within the same step budget.
    twice = QpProblem(H=np.eye(2), g=np.array([-1e4, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.array([[1.0, 0.0], [1.0, 0.0]]),
                      l=np.array([-inf, -inf]), u=np.array([1.0, 1.0]), structure=94)  # fmt: skip
    guess = ActiveSetGuess()
    assert guess.polish(twice, np.array([1.0, 0.0])) is not None
    x = guess.try_solve(twice)
    assert x is not None and abs(x[0] - 1.0) < 1e-6 and twice.violation(x) < 1e-8


def test_every_polish_solve_is_regularised_so_a_correction_to_dependent_rows_costs_one_solve() -> None:
    """The polish starts from the rows tight at the backend's point (none here) and adds every
    violated row at once: both copies of x₀ ≤ 1, linearly dependent. Solved regularised, as every
    polish solve is, that set gives the optimum at once: two KKT solves, also within a budget of
    two (an unregularised solve would fail on it and spend a third). From the vertex itself, both
    rows tight: one solve."""
    inf = np.inf
    twice = QpProblem(H=np.eye(2), g=np.array([-3.0, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.array([[1.0, 0.0], [1.0, 0.0]]),
                      l=np.array([-inf, -inf]), u=np.array([1.0, 1.0]), structure=95)  # fmt: skip
    for steps in (4, 2):
        guess = ActiveSetGuess(polish_steps=steps)
        x = guess.polish(twice, np.zeros(2))
        assert x is not None and guess.solves == 2 and guess.polished == 1, steps
        np.testing.assert_array_equal(guess.active, [0, 1])
        assert abs(x[0] - 1.0) < 1e-8 and x[1] == 0.0 and twice.violation(x) < 1e-8
    guess = ActiveSetGuess()
    assert guess.polish_steps == 4  # the polish's default budget of KKT solves
    x = guess.polish(twice, np.array([1.0, 0.0]))
    assert x is not None and guess.solves == 1 and abs(x[0] - 1.0) < 1e-8


def test_a_polish_correction_adds_every_violated_row_on_its_side_and_drops_every_wrong_sign_one() -> None:
    """min ½‖x − target‖² in the box −1 ≤ x ≤ 1 (rows of C). From a backend's point with nothing
    tight, one all-at-once correction adds the four violated rows, two upper and two lower: two
    solves (one row at a time would take five, beyond the polish's four). From a point where x₀
    and x₂ sit at their upper limits, the first solve finds x₂'s multiplier of the wrong sign and
    x₁, x₃, x₄ beyond their limits: one correction drops the one and adds the three."""
    target = np.array([3.0, -2.5, 0.2, 2.0, -1.5, 0.0])
    box = QpProblem(H=np.eye(6), g=-target, A=np.zeros((0, 6)), b=np.zeros(0), C=np.eye(6), l=np.full(6, -1.0), u=np.full(6, 1.0),
                    structure=96)  # fmt: skip
    optimum = np.clip(target, -1.0, 1.0)
    guess = ActiveSetGuess()
    for polished, start in enumerate((np.zeros(6), np.array([1.0, 0.0, 1.0, 0.0, 0.0, 0.0])), start=1):
        x = guess.polish(box, start)
        assert x is not None and guess.solves == 2 * polished and (guess.polished, guess.polish_failures) == (polished, 0)
        np.testing.assert_allclose(x, optimum, atol=1e-10)
        np.testing.assert_array_equal(guess.active, [0, 1, 3, 4])
        np.testing.assert_array_equal(guess.upper, [True, False, True, False])


def test_settle_reads_no_multiplier_left_by_an_earlier_solve() -> None:
    """A search first solves {x₀, x₁} at their upper limits, where x₁'s multiplier has the wrong
    sign, and ends at {x₀}. Settling at the optimum then takes {x₀} and returns its KKT point:
    the multipliers of the earlier, larger set are not checked (settle checks none)."""
    p = QpProblem(H=np.eye(3), g=-np.array([3.0, 3.0, 0.0]), A=np.zeros((0, 3)), b=np.zeros(0), C=np.eye(3), l=np.full(3, -1.0),
                  u=np.full(3, 1.0), structure=97)  # fmt: skip
    guess = ActiveSetGuess()
    assert guess.try_solve(p) is not None
    p.g[...] = -np.array([3.0, 0.5, 0.0])
    before = guess.solves
    x = guess.try_solve(p)
    assert x is not None and guess.solves - before == 2
    np.testing.assert_array_equal(guess.active, [0])
    settled = guess.settle(p, x)
    assert settled is not None
    np.testing.assert_array_equal(settled, [1.0, 0.5, 0.0])


def test_a_qpsolvers_backend_named_without_the_prefix_gets_the_settings(monkeypatch) -> None:
    """A name qpsolvers lists (other than osqp/proxqp, which giwbc takes itself) goes to that
    qpsolvers backend, case-insensitively, with the settings given. (Only osqp and proxqp are
    installed here: a third name is listed, and its solves are osqp's, recorded.)"""
    from giwbc.control.qp.proxsuite_build import import_qpsolvers

    qpsolvers = import_qpsolvers()
    real, calls = qpsolvers.solve_problem, []

    def solve_problem(problem, solver, **settings):
        calls.append((solver, settings))
        return real(problem, solver="osqp", **settings)

    monkeypatch.setattr(qpsolvers, "available_solvers", [*qpsolvers.available_solvers, "other"])
    monkeypatch.setattr(qpsolvers, "solve_problem", solve_problem)
    via = make_solver("Other", eps_abs=1e-9, eps_rel=1e-9, polish=True)
    assert isinstance(via, QpsolversSolver) and via.name == "other"
    solution = via.solve(_box_problem([0.5, 2.0], [1.0, 1.0]))
    assert solution.ok and np.abs(solution.x - [0.5, 1.0]).max() < 1e-6
    assert calls == [("other", {"initvals": None, "eps_abs": 1e-9, "eps_rel": 1e-9, "polish": True})]


def test_a_row_held_at_equal_limits_takes_a_multiplier_of_either_sign_past_an_equality_row() -> None:
    """x₂ = 0 is an equality (a row of A); the second row of C holds x₀ at l = u = 0.5. Last
    tick's set had that row at its upper side; now the target pulls x₀ below 0.5: the multiplier
    has the "wrong" sign for an upper limit, but the row is an equality (its own l and u, read
    past the equality row, are equal): the set is optimal at once, one solve. Two failed polishes
    count two."""
    p = QpProblem(H=np.eye(3), g=np.array([0.0, -0.2, 0.0]), A=np.array([[0.0, 0.0, 1.0]]), b=np.zeros(1),
                  C=np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]), l=np.array([-1.0, 0.5]), u=np.array([1.0, 0.5]), structure=98)  # fmt: skip
    guess = ActiveSetGuess()
    guess.learn(p, np.array([0.5, 0.2, 0.0]), np.array([0.0, 1.0]))
    np.testing.assert_array_equal(guess.active, [1])
    np.testing.assert_array_equal(guess.upper, [True])
    x = guess.try_solve(p)
    assert x is not None and guess.solves == 1
    np.testing.assert_allclose(x, [0.5, 0.2, 0.0], atol=1e-14)
    singular = QpProblem(H=np.diag([1.0, 0.0]), g=np.array([-1.0, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.array([[1.0, 0.0]]),
                         l=np.array([-np.inf]), u=np.array([0.5]), structure=99)  # fmt: skip
    for _ in range(2):
        assert guess.polish(singular, np.array([0.5, 0.0])) is None
    assert (guess.polished, guess.polish_failures) == (0, 2)


def test_proxsuites_iterate_is_polished_else_settled_within_its_accuracy_else_the_tick_fails() -> None:
    """The same row twice, x₀ ≤ 1, pulled hard (λ ≈ ½|g₀|): proxsuite solves it, the polish does
    not (regularised, the shared multiplier bends the rows by δ|λ| beyond the tolerance, 1e-8),
    and the settled point — the rows' KKT point — is accepted when within proxsuite's accuracy
    (max(eps_abs, 1e-7)) of feasible: bent by 5e-8 it is the answer, with proxsuite's status and
    the rows; bent by 5e-7 with eps_abs = 1e-8 it is not, and the tick fails. A box QP is polished
    into its exact optimum; without the guess, a repeated problem is proxsuite's again."""
    inf = np.inf

    def twice(pull: float) -> QpProblem:
        return QpProblem(H=np.eye(2), g=np.array([-pull, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.array([[1.0, 0.0], [1.0, 0.0]]),
                         l=np.array([-inf, -inf]), u=np.array([1.0, 1.0]), structure=100)  # fmt: skip

    solver = ProxsuiteSolver()
    p = twice(1e5)
    solution = solver.solve(p)
    assert solution.status is QpStatus.SOLVED and (solver.guess.polished, solver.guess.polish_failures) == (0, 1)
    assert abs(solution.x[0] - 1.0) < 1e-7 and abs(solution.x[0] - 1.0) > 1e-8 and 1e-8 < p.violation(solution.x) < 1e-7
    assert solution.rows is not None and np.array_equal(solution.rows, [solution.x[0]] * 2)
    strict = ProxsuiteSolver(eps_abs=1e-8)
    failed = strict.solve(twice(1e6))
    assert failed.status is QpStatus.FAILED and "no KKT point near its iterate is feasible" in failed.message
    assert strict.guess.polish_failures == 1
    box = _box_problem([0.5, 2.0], [1.0, 1.0])
    plain = ProxsuiteSolver(active_set_guess=False)
    assert plain.guess is None
    for _ in range(2):
        solution = plain.solve(box)
        assert solution.status is QpStatus.SOLVED and solution.message != "active-set guess"
        np.testing.assert_allclose(solution.x, [0.5, 1.0], atol=1e-12)


def test_a_warm_tick_with_no_answer_is_retried_cold_with_the_rest_of_its_budget(monkeypatch) -> None:
    """A problem solved, then changed in place (the same object and structure: a warm tick) into
    the same row twice pulled hard, whose settled point is beyond eps_abs = 1e-8 (the guess off,
    which would answer it with one of the rows): proxsuite solves it but no answer is accepted,
    so the tick is retried from a cold start. With a large budget the iterations reported are
    both attempts' (the first one's measured with the retry off, the retry's as a cold solve);
    with the default 10 outer iterations the retry gets only those the first attempt left, and
    runs out of them. A proxsuite error during the retry fails the tick with the iterations
    spent and the time taken, and the next tick starts over."""
    inf = np.inf

    def solver_after_a_tick(**settings) -> tuple[ProxsuiteSolver, QpProblem]:
        solver = ProxsuiteSolver(eps_abs=1e-8, active_set_guess=False, **settings)
        p = QpProblem(H=np.eye(2), g=np.array([-0.5, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.array([[1.0, 0.0], [1.0, 0.0]]),
                      l=np.array([-inf, -inf]), u=np.array([1.0, 1.0]), structure=101)  # fmt: skip
        assert solver.solve(p).ok
        p.g[0] = -1e6
        return solver, p

    cold = ProxsuiteSolver(eps_abs=1e-8, active_set_guess=False, max_iter=100).solve(solver_after_a_tick()[1])
    solver, p = solver_after_a_tick(retry_cold=False, max_iter=100)
    first = solver.solve(p)
    solver, p = solver_after_a_tick(max_iter=100)
    retried = solver.solve(p)
    assert not cold.ok and not first.ok and not retried.ok and min(cold.iterations, first.iterations) > 0
    assert "no KKT point near its iterate is feasible" in retried.message
    assert retried.iterations == first.iterations + cold.iterations
    solver, p = solver_after_a_tick()
    budgeted = solver.solve(p)
    assert budgeted.status is QpStatus.MAX_ITER and first.iterations < budgeted.iterations < first.iterations + cold.iterations

    solver, p = solver_after_a_tick()

    def broken(problem: QpProblem) -> None:
        raise RuntimeError("out of memory")

    monkeypatch.setattr(solver, "_init", broken)
    failed, elapsed = _timed(solver, p)
    assert failed.status is QpStatus.FAILED and failed.message == "proxsuite error: out of memory"
    assert failed.iterations == first.iterations and failed.x.shape == (2,) and np.all(np.isnan(failed.x))
    assert 0.0 <= failed.solve_time <= elapsed
    monkeypatch.undo()
    p.g[0] = -0.5
    again = solver.solve(p)
    assert again.ok and abs(again.x[0] - 0.5) < 1e-8


@pytest.mark.parametrize("layout", ["controller", "separate", "bounded"])
def test_the_guess_reads_arrays_replaced_on_the_same_problem_and_keeps_its_set_for_a_copy(layout: str) -> None:
    """One problem object whose arrays are replaced, one at a time, by new arrays of other values
    (not refilled in place: the controller's views no longer span A and C, l and u): every answer
    is the optimum of the problem as it is now (its KKT conditions hold). A copy of the problem
    (new arrays, the same sizes) is answered from the active set learned on the original, in one
    KKT solve."""
    reference = make_solver("proxsuite", **BACKENDS["proxsuite"], active_set_guess=False, polish=False, deterministic=False)
    for order in (("C", "A", "l", "u"), ("A", "C", "u", "l")):  # (each of A, C, l, u first: while its pair is adjacent)
        p = random_qp(np.random.default_rng(13), n=6, n_eq=2, n_in=5, structure=72)
        if layout != "bounded":
            p.lb = p.ub = None
            p.l, p.u = p.l - 0.3, p.u + 0.3
            if layout == "controller":
                p = _controller_layout(p)
        guess = ActiveSetGuess()
        assert guess.polish(p, reference.solve(p.copy()).x) is not None
        before = guess.solves
        copy = guess.try_solve(p.copy())
        assert copy is not None and guess.solves - before == 1
        assert guess.try_solve(p) is not None and guess.solves - before == 2  # (the original again: the one prepared last)
        for name in order:
            setattr(p, name, getattr(p, name) * {"A": 1.01, "C": 0.99, "l": 1.02, "u": 1.02}[name])  # a new array
            x = guess.try_solve(p)
            assert x is not None, name  # (checked by its KKT conditions: a warm raw proxsuite can stop early after l moved)
            assert p.violation(x) < 1e-9 and kkt_residual(_with_infinite_bounds(p) if p.lb is None else p, x) < 1e-7, name


def test_without_the_polish_a_warm_proxsuite_does_not_report_a_wrong_point_as_solved() -> None:
    """Raw proxsuite (no guess, no polish), warm-started after the limits ``l`` moved by 2 %: its
    own test stops at once on the previous point for most of these QPs (27 of 40 measured) unless
    the duality gap is checked too, which giwbc turns on when nothing else checks optimality."""
    wrong = 0
    for seed in range(40):
        raw = make_solver("proxsuite", **BACKENDS["proxsuite"], active_set_guess=False, polish=False, deterministic=False)
        p = random_qp(np.random.default_rng(seed), n=6, n_eq=2, n_in=5, structure=72)
        p.lb = p.ub = None
        p.l, p.u = p.l - 0.3, p.u + 0.3
        assert raw.solve(p).ok
        p.l = p.l * 1.02
        solution = raw.solve(p)
        wrong += solution.ok and kkt_residual(_with_infinite_bounds(p), solution.x) > 1e-5
    assert wrong == 0
    assert make_solver("proxsuite", polish=False, check_duality_gap=False)._settings["check_duality_gap"] is False  # (a caller's choice stays)
    assert "check_duality_gap" not in make_solver("proxsuite")._settings  # (the polish checks optimality itself)
