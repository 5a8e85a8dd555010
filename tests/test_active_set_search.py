"""The guess's search from last tick's active set (``ActiveSetGuess.try_solve``): one row in, one
row out per KKT solve, bounded, with cycle detection — and its answers are the backend's optimum.
"""

from __future__ import annotations

import numpy as np
import pytest

from giwbc.control import ProxsuiteSolver
from giwbc.control.qp import ActiveSetGuess, QpProblem
from giwbc.locomotion.simulation import simulate_walk

INF = np.inf


def _box(target: np.ndarray, limit: float = 1.0, structure: int = 201) -> QpProblem:
    """min ½‖x − target‖² s.t. −limit ≤ x ≤ limit (rows of C): the optimum clips the target,
    its active set is the coordinates beyond the limit (upper side where positive)."""
    n = len(target)
    return QpProblem(H=np.eye(n), g=-np.asarray(target, dtype=float), A=np.zeros((0, n)), b=np.zeros(0), C=np.eye(n),
                     l=np.full(n, -limit), u=np.full(n, limit), structure=structure)  # fmt: skip


def test_each_correction_exchanges_one_row_so_k_missing_rows_take_k_plus_one_solves() -> None:
    """From an empty active set, an optimum with 4 rows active (two upper, two lower limits) is
    reached by adding the most violated row at each solve: 5 KKT solves, the last one optimal and
    exact; the active set found, with its sides, is the next guess (one solve for the same
    problem again)."""
    target = np.array([3.0, -2.5, 0.2, 2.0, -1.5, 0.0])
    p = _box(target)
    guess = ActiveSetGuess()
    x = guess.try_solve(p)
    assert x is not None and guess.solves == 5 and guess.hits == 1
    np.testing.assert_array_equal(x, np.clip(target, -1.0, 1.0))
    np.testing.assert_array_equal(guess.active, [0, 1, 3, 4])
    np.testing.assert_array_equal(guess.upper, [True, False, True, False])
    again = guess.try_solve(p)
    assert again is not None and guess.solves == 6
    np.testing.assert_array_equal(again, x)


def test_a_wrong_sign_row_leaves_while_a_violated_one_joins_in_the_same_solve() -> None:
    """Last tick's set holds x₀ at its upper limit; now the target moved to the other side: the
    multiplier of x₀'s row has the wrong sign and x₁ violates its lower limit. One correction
    drops the first and adds the second: 2 solves."""
    guess = ActiveSetGuess()
    p = _box(np.array([3.0, 0.0, 0.0]))
    assert guess.try_solve(p) is not None
    np.testing.assert_array_equal(guess.active, [0])
    p.g[...] = -np.array([0.5, -4.0, 0.0])
    before = guess.solves
    x = guess.try_solve(p)
    assert x is not None and guess.solves - before == 2
    np.testing.assert_array_equal(x, [0.5, -1.0, 0.0])
    np.testing.assert_array_equal(guess.active, [1])
    np.testing.assert_array_equal(guess.upper, [False])


@pytest.mark.parametrize("steps", [3, 4])
def test_the_search_gives_up_at_its_step_bound_and_the_backend_answers(steps: int) -> None:
    """Four rows to add from an empty set: 5 solves needed. Within a bound of 3 or 4 solves the
    guess gives up (exactly ``steps`` solves spent) and proxsuite + polish answer the tick with
    the same optimum; the active set the backend found answers the next tick (exactly: without
    the polish's regularisation)."""
    target = np.array([3.0, -2.5, 0.2, 2.0, -1.5, 0.0])
    solver = ProxsuiteSolver()
    solver.guess.steps = steps
    p = _box(target)
    first = solver.solve(p)  # (a cold start: the backend, which teaches the guess)
    solver.guess.reset()  # forget it: the next tick's guess starts from nothing
    before = solver.guess.solves
    tries, hits = solver.guess.tries, solver.guess.hits
    second = solver.solve(p)
    assert second.ok and second.message != "active-set guess"
    assert (solver.guess.tries, solver.guess.hits) == (tries + 1, hits)
    assert solver.guess.solves - before >= steps  # the guess's, then the polish's
    np.testing.assert_allclose(second.x, np.clip(target, -1.0, 1.0), atol=1e-10)  # (the polish: regularised)
    np.testing.assert_allclose(first.x, second.x, atol=1e-10)
    third = solver.solve(p)
    assert third.message == "active-set guess"
    np.testing.assert_array_equal(third.x, np.clip(target, -1.0, 1.0))  # unregularised: exact
    # The bound counts solves: the search alone, from an empty set, spends exactly `steps`.
    guess = ActiveSetGuess(steps=steps)
    assert guess.try_solve(_box(target)) is None and guess.solves == steps and guess.hits == 0


def test_a_set_that_comes_back_ends_the_search_before_its_bound() -> None:
    """The same row twice, with a large multiplier: the KKT system is singular; regularised, the
    two rows share a multiplier of ~5e5 and each is bent by δ|λ| = 5e-7, beyond the tolerance,
    while no inactive row is violated and no sign is wrong — the exchange leaves the set as it
    was. The search stops at the repeat (2 solves: singular, regularised), not after its 12."""
    p = QpProblem(H=np.eye(2), g=np.array([-1e6, 0.0]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.array([[1.0, 0.0], [1.0, 0.0]]),
                  l=np.array([-INF, -INF]), u=np.array([1.0, 1.0]), structure=202)  # fmt: skip
    guess = ActiveSetGuess()
    assert guess.steps == 12
    guess.learn(p, np.array([1.0, 0.0]), np.array([1.0, 1.0]))  # both rows active at their upper limits
    np.testing.assert_array_equal(guess.active, [0, 1])
    assert guess.try_solve(p) is None
    assert guess.solves == 2 and guess.hits == 0
    # A smaller multiplier bends the rows within the tolerance: the regularised candidate is the answer.
    p.g[0] = -1e4
    x = guess.try_solve(p)
    assert x is not None and abs(x[0] - 1.0) < 1e-8 and guess.solves == 4


@pytest.mark.slow
def test_on_a_g1_walk_the_search_answers_nearly_every_tick_with_the_backends_optimum(g1, monkeypatch) -> None:
    """A 3 s closed-loop MuJoCo walk at 0.3 m/s (seed 0): every tick whose guess needed a
    correction (a changed active set: friction rows at a sole's edge, contact switches) is
    answered again by proxsuite + polish from scratch (no guess): the same optimum, to 1e-11 of
    the answer's scale (the polish's regularisation bends its rows by ~1e-12 |λ|) — both are
    exact KKT points of the same QP. The backend answers fewer than
    2 % of the ticks (the all-at-once corrections left ~8 %), and the walk neither falls nor
    fails."""
    searched: list[tuple[QpProblem, np.ndarray]] = []
    ticks = {"guess": 0, "all": 0}
    original = ActiveSetGuess.try_solve

    def recording(self: ActiveSetGuess, p: QpProblem) -> np.ndarray | None:
        before = self.solves
        x = original(self, p)
        ticks["all"] += 1
        if x is not None:
            ticks["guess"] += 1
            if self.solves - before > 1 and len(searched) < 40:
                searched.append((p.copy(), x.copy()))
        return x

    monkeypatch.setattr(ActiveSetGuess, "try_solve", recording)
    run = simulate_walk(g1, (0.3, 0.0, 0.0), 3.0, seed=0)
    monkeypatch.undo()
    assert not run.fell and run.wbc_failures == 0 and run.steps >= 4
    assert ticks["all"] >= 1400
    assert ticks["all"] - ticks["guess"] < 0.02 * ticks["all"], ticks
    assert len(searched) >= 20  # the search worked on many ticks
    for p, x in searched:
        reference = ProxsuiteSolver(active_set_guess=False).solve(p.copy())
        assert reference.ok
        scale = max(1.0, float(np.abs(reference.x).max()))
        np.testing.assert_allclose(x, reference.x, rtol=0, atol=1e-11 * scale)
        assert p.violation(x) < 1e-8


def test_rows_whose_active_limit_opened_to_infinity_leave_the_set() -> None:
    """Last tick x₀ was held at l = u = 1 (an equality written as a row: a contact force bound
    closed to zero before touch-down); now its limits are open (±inf, its ramp started). The set
    from last tick has an infinite right-hand side: the search drops that row (after the
    unregularised and regularised solves fail) and answers the unconstrained optimum — 3 solves,
    not the backend."""
    p = QpProblem(H=np.eye(2), g=np.array([-3.0, 0.5]), A=np.zeros((0, 2)), b=np.zeros(0), C=np.eye(2),
                  l=np.array([1.0, -INF]), u=np.array([1.0, INF]), structure=203)  # fmt: skip
    guess = ActiveSetGuess()
    x = guess.try_solve(p)
    assert x is not None and np.array_equal(x, [1.0, -0.5])
    np.testing.assert_array_equal(guess.active, [0])
    p.l[0], p.u[0] = -INF, INF
    before = guess.solves
    x = guess.try_solve(p)
    assert x is not None and guess.solves - before == 3 and len(guess.active) == 0
    np.testing.assert_allclose(x, [3.0, -0.5], atol=1e-12)


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_only_the_rows_whose_active_side_opened_leave_and_equality_rows_are_skipped(side: float) -> None:
    """With an equality row first (x₂ = 0) and the row of x₀ second in C: last tick x₀ was held
    at its upper (lower) limit ±1; now that limit opened to ±inf while the other stays finite.
    The search drops that row — read at its own index, past the equality and the row before it,
    on its active side — and answers the unconstrained x₀ = ±3; the try is counted."""
    lower, upper = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    p = QpProblem(H=np.eye(3), g=-np.array([3.0 * side, 0.2, 0.0]), A=np.array([[0.0, 0.0, 1.0]]), b=np.zeros(1),
                  C=np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]), l=lower, u=upper, structure=204)  # fmt: skip
    guess = ActiveSetGuess()
    x = guess.try_solve(p)
    assert x is not None and np.array_equal(x, [side, 0.2, 0.0])
    np.testing.assert_array_equal(guess.active, [1])
    np.testing.assert_array_equal(guess.upper, [side > 0])
    (p.u if side > 0 else p.l)[1] = side * INF
    before = guess.solves
    x = guess.try_solve(p)
    assert x is not None and guess.solves - before == 3 and len(guess.active) == 0
    np.testing.assert_allclose(x, [3.0 * side, 0.2, 0.0], atol=1e-12)
    assert (guess.tries, guess.hits) == (2, 2)


def test_of_two_wrong_sign_rows_only_the_worst_leaves_per_solve() -> None:
    """Last tick x₀ and x₁ were both held at their upper limits; now both targets moved inside:
    both multipliers have the wrong sign. One row leaves per correction, the worst first (x₁,
    whose target moved further): 3 solves, not 2."""
    guess = ActiveSetGuess()
    p = _box(np.array([3.0, 3.0, 0.0]))
    assert guess.try_solve(p) is not None
    np.testing.assert_array_equal(guess.active, [0, 1])
    p.g[...] = -np.array([0.5, -0.5, 0.0])
    before = guess.solves
    guess.steps = 1  # one solve: x₁ has left, x₀ is still there
    assert guess.try_solve(p) is None
    np.testing.assert_array_equal(guess.active, [0])
    guess.steps = 12
    x = guess.try_solve(p)
    assert x is not None and guess.solves - before == 1 + 2
    np.testing.assert_array_equal(x, [0.5, -0.5, 0.0])
    assert len(guess.active) == 0


def test_an_answer_is_not_overwritten_by_the_next_solve() -> None:
    """The guess's answer is the caller's: solving another problem (same KKT size) leaves it as it was."""
    guess = ActiveSetGuess()
    first = guess.try_solve(_box(np.array([3.0, 0.5, 0.0])))
    kept = first.copy()
    second = guess.try_solve(_box(np.array([-3.0, 0.25, 0.0])))
    assert first is not None and second is not None
    np.testing.assert_array_equal(first, kept)
    np.testing.assert_array_equal(second, [-1.0, 0.25, 0.0])


def test_recover_answers_the_search_from_the_tight_rows_else_the_polish_at_ten_times_the_slack() -> None:
    """Points near the optimum of small random QPs (``x* +`` Gaussian noise of 5e-6 or 3e-5 per
    variable) where the polish from the rows within ``slack = 1e-5`` finds no optimal set:
    :meth:`ActiveSetGuess.recover` answers, bit for bit, what the one-row search from those rows
    answers, or — where the search fails too — what the polish from the rows within ``slack / 10``,
    else ``10 slack``, answers (the same deterministic, regularised KKT solves: its answer depends
    on the point only through which rows fall within each threshold), and that answer is the
    optimum (``x*`` to 1e-9). Both the search and the 10·slack polish are needed on some of them."""
    from test_control_qp import random_qp

    stages = {"search": 0, "tenfold": 0, "tenth": 0, "none": 0}
    slack = 1e-5
    for seed in range(400):
        rng = np.random.default_rng(seed)
        n, n_eq, n_in = int(rng.integers(6, 13)), int(rng.integers(0, 4)), int(rng.integers(2, 12))
        p = random_qp(rng, n=n, n_eq=n_eq, n_in=n_in, structure=1)
        optimum = ActiveSetGuess(steps=200).try_solve(p)  # (a long search from the empty set)
        if optimum is None:
            continue
        for scale in (5e-6, 3e-5):
            x = optimum + rng.normal(scale=scale, size=n)
            if ActiveSetGuess().polish(p, x, slack) is not None:
                continue
            search = ActiveSetGuess()
            search._tight(p, x, slack)
            expected = search._search(p, search.steps)
            stage = "search"
            for name, other in (("tenth", 0.1 * slack), ("tenfold", 10.0 * slack)):
                if expected is not None:
                    break
                expected, stage = ActiveSetGuess().polish(p, x, other), name
            recovered = ActiveSetGuess().recover(p, x, slack)
            if expected is None:
                stages["none"] += 1
                assert recovered is None
                continue
            stages[stage] += 1
            assert recovered is not None
            np.testing.assert_array_equal(recovered, expected)
            np.testing.assert_allclose(recovered, optimum, rtol=0, atol=1e-9)
    assert stages["search"] >= 20 and stages["tenfold"] >= 5, stages


def _reference_exchange(check: np.ndarray, active: np.ndarray, upper: np.ndarray, ne: int, rows: int, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The exchange rule spelled out: drop the active row of worst multiplier sign beyond ``tol``;
    add the inactive inequality row violated most beyond ``tol`` (upper side first on a tie, then
    the lower row index); the set sorted by row."""
    k = len(active)
    keep = np.ones(k, dtype=bool)
    if k:
        signed = check[2 * rows : 2 * rows + k]
        keep[int(signed.argmax())] = signed.max() <= tol
    violation = check[: 2 * rows].reshape(2, rows)[:, ne:].copy()
    violation[:, active] = -np.inf
    side, row = divmod(int(violation.argmax()), rows - ne)
    new_active, new_upper = list(active[keep]), list(upper[keep])
    if violation[side, row] > tol:
        new_active.append(row)
        new_upper.append(side == 0)
    order = np.argsort(new_active, kind="stable")
    return np.array(new_active, dtype=np.int64)[order], np.array(new_upper, dtype=bool)[order]


def test_the_exchange_takes_the_rule_s_decisions_on_ties_equalities_and_active_rows() -> None:
    """``_exchange`` (which masks the last solve's check buffer in place) against the rule spelled
    out, on 400 random checks drawn from few values (ties between rows and sides everywhere),
    with equality rows and active rows among the most violated: the same row leaves, the same
    row joins on the same side, the set stays sorted."""
    rng = np.random.default_rng(15)
    n, ne, ni = 5, 2, 9
    A = rng.normal(size=(ne, n))
    p = QpProblem(H=np.eye(n), g=np.zeros(n), A=A, b=np.zeros(ne), C=rng.normal(size=(ni, n)),
                  l=np.full(ni, -1.0), u=np.full(ni, 1.0), structure=203)  # fmt: skip
    guess = ActiveSetGuess()
    guess._prepare(p)
    rows = ne + ni
    tol = guess.tolerance
    changed = 0
    for _ in range(400):
        k = int(rng.integers(0, 5))
        active = np.sort(rng.choice(ni, size=k, replace=False)).astype(np.int64)
        upper = rng.random(k) < 0.5
        guess.active, guess.upper = active, upper
        check = rng.choice([-1.0, 0.0, 0.5 * tol, 2.0 * tol, 1.0, 3.0], size=2 * rows + k)
        check[rng.random(len(check)) < 0.1] = 5.0  # the largest values on equality and active rows too
        guess._check[: len(check)] = check
        expected = _reference_exchange(check.copy(), active, upper, ne, rows, tol)
        guess._exchange(ne, rows, k, tol)
        np.testing.assert_array_equal(guess.active, expected[0])
        np.testing.assert_array_equal(guess.upper, expected[1])
        assert guess.active.dtype == np.int64 and guess.upper.dtype == bool
        assert np.all(np.diff(guess.active) > 0)
        changed += not np.array_equal(guess.active, active)
    assert changed > 300  # (most draws exchange something)


def test_on_a_tie_the_upper_side_joins_and_lands_in_order_among_the_active_rows() -> None:
    """Rows 0 and 3 held at their upper limits; rows 1 (below) and 2 (above) violated by the
    same 2: one exchange (a bound of one solve) adds row 2, upper side, between 0 and 3; the
    full search then reaches the clipped optimum."""
    target = np.array([3.0, -3.0, 3.0, 2.0])
    p = _box(target, structure=204)
    guess = ActiveSetGuess(steps=1)
    guess.learn(p, np.clip(target, -1.0, 1.0), np.array([1.0, 0.0, 0.0, 1.0]))
    assert guess.try_solve(p) is None
    np.testing.assert_array_equal(guess.active, [0, 2, 3])
    np.testing.assert_array_equal(guess.upper, [True, True, True])
    guess.steps = 12
    x = guess.try_solve(p)
    assert x is not None
    np.testing.assert_array_equal(x, np.clip(target, -1.0, 1.0))
    np.testing.assert_array_equal(guess.active, [0, 1, 2, 3])
    np.testing.assert_array_equal(guess.upper, [True, False, True, True])
