"""Variables a problem declares held at zero (``QpProblem.fixed``: a broken contact's pinned
wrench) are eliminated from the active-set guess's KKT system: a smaller system, the same optimum,
those variables exactly zero."""

from __future__ import annotations

import numpy as np
import pytest

from giwbc.control.qp import ActiveSetGuess, QpProblem
from giwbc.locomotion.simulation import simulate_walk


def _pinned_problem(seed: int = 0, structure: int = 301, pinned: tuple[int, ...] = (5, 6, 7)) -> QpProblem:
    """A random strictly convex QP in 9 variables: 2 general equalities, a unit row ``x_i = 0``
    for each ``pinned`` i (default 5, 6, 7; also coupled to the others through ``H`` and the
    inequalities), and 6 two-sided inequality rows, several of them active at the optimum."""
    rng = np.random.default_rng(seed)
    n = 9
    L = rng.normal(size=(n, n))
    H = L @ L.T + n * np.eye(n)
    A = np.zeros((2 + len(pinned), n))
    A[:2] = rng.normal(size=(2, n))
    A[2 + np.arange(len(pinned)), list(pinned)] = 1.0
    b = np.concatenate([rng.normal(size=2), np.zeros(len(pinned))])
    C = rng.normal(size=(6, n))
    return QpProblem(H=H, g=rng.normal(size=n) * 10.0, A=A, b=b, C=C, l=np.full(6, -1.0), u=np.full(6, 1.0), structure=structure)


@pytest.mark.parametrize("pinned", [(5, 6, 7), (0, 2, 4, 8)])
def test_eliminating_declared_zero_variables_gives_the_same_optimum_from_a_smaller_system(pinned: tuple[int, ...]) -> None:
    """The same QP solved by the guess with and without the declaration: the same answer (to
    1e-12 of its scale: only rounding differs), the fixed variables exactly zero, the answer
    feasible; the declared solve's KKT system is 2 rows smaller per pinned variable (the
    variable, its equality row), and it keeps its active set from tick to tick like the full
    one. The pinned variables one block (5, 6, 7) or scattered, the first and last included,
    with gaps of one kept variable (0, 2, 4, 8)."""
    with_active_rows = 0
    count = len(pinned)
    for seed in range(8):
        full = _pinned_problem(seed, pinned=pinned)
        reduced = full.copy()
        reduced.fixed = (np.array(pinned), 2 + np.arange(count))
        plain, eliminating = ActiveSetGuess(), ActiveSetGuess()
        x = plain.try_solve(full)
        y = eliminating.try_solve(reduced)
        assert (x is None) == (y is None)  # (the search from an empty set gives up on both, or on neither)
        if x is None:
            continue
        with_active_rows += len(plain.active) >= 1  # (the multiplier signs were checked)
        np.testing.assert_array_equal(plain.active, eliminating.active)
        np.testing.assert_allclose(y, x, rtol=0, atol=1e-12 * max(1.0, float(np.abs(x).max())))
        assert np.all(y[list(pinned)] == 0.0)
        assert reduced.violation(y) < 1e-9
        k = len(eliminating.active)
        assert eliminating._views[0].shape[0] == plain._views[0].shape[0] - 2 * count == 9 - count + 2 + k
        before = eliminating.solves
        assert eliminating.try_solve(reduced) is not None and eliminating.solves == before + 1
        # The declaration withdrawn (a contact made again): the full system, the same answer.
        reduced.fixed = None
        z = eliminating.try_solve(reduced)
        assert z is not None and eliminating._views[0].shape[0] == plain._views[0].shape[0]
        np.testing.assert_allclose(z, x, rtol=0, atol=1e-12 * max(1.0, float(np.abs(x).max())))
    assert with_active_rows >= 3


@pytest.mark.parametrize("side", ["lb", "ub"])
def test_fixed_variables_with_a_finite_bound_are_not_eliminated(side: str) -> None:
    """A bound row of an eliminated variable would be a zero row of the KKT system: with a
    finite variable bound (lower or upper) on a declared variable the guess keeps the full
    system."""
    p = _pinned_problem(1)
    n = p.n
    p.lb, p.ub = np.full(n, -np.inf), np.full(n, np.inf)
    getattr(p, side)[6] = -5.0 if side == "lb" else 5.0
    p.fixed = (np.array([5, 6, 7]), np.array([2, 3, 4]))
    guess = ActiveSetGuess()
    x = guess.try_solve(p)
    assert x is not None and p.violation(x) < 1e-9
    assert guess._views[0].shape[0] == n + p.n_eq + len(guess.active)
    # The bound opened again (the same arrays), the same variables declared anew: now eliminated.
    getattr(p, side)[6] = -np.inf if side == "lb" else np.inf
    p.fixed = (np.array([5, 6, 7]), np.array([2, 3, 4]))
    x = guess.try_solve(p)
    assert x is not None and p.violation(x) < 1e-9 and np.all(x[[5, 6, 7]] == 0.0)
    assert guess._views[0].shape[0] == n - 3 + p.n_eq - 3 + len(guess.active)


def test_in_single_support_the_swing_wrench_is_declared_fixed_and_answered_zero(g1, monkeypatch) -> None:
    """A 1.6 s MuJoCo walk at 0.3 m/s (seed 0): on every tick with a pinned contact the problem
    declares exactly that contact's 6 force columns and 6 motion rows (unit rows, zero right-hand
    side), none on the others; the answer has that wrench exactly zero and equals the optimum
    of the same problem solved without the declaration (to 1e-11 of its scale)."""
    seen: list[tuple[QpProblem, np.ndarray]] = []
    declared = {"ticks": 0, "none": 0}
    original = ActiveSetGuess.try_solve

    def recording(self: ActiveSetGuess, p: QpProblem) -> np.ndarray | None:
        x = original(self, p)
        if p.fixed is None:
            declared["none"] += 1
        else:
            declared["ticks"] += 1
            if x is not None and declared["ticks"] % 20 == 1:
                seen.append((p.copy(), x.copy()))
        return x

    monkeypatch.setattr(ActiveSetGuess, "try_solve", recording)
    run = simulate_walk(g1, (0.3, 0.0, 0.0), 1.6, seed=0)
    monkeypatch.undo()
    assert not run.fell and run.wbc_failures == 0 and run.steps >= 1
    assert declared["ticks"] >= 100 and declared["none"] >= 100  # single and double support both
    assert len(seen) >= 5
    for p, x in seen:
        columns, rows = p.fixed
        assert len(columns) == len(rows) == 6
        assert columns[0] >= p.n - 12 and np.all(np.diff(columns) == 1) and np.all(np.diff(rows) == 1)
        unit = np.zeros((6, p.n))
        unit[:, columns] = np.eye(6)
        np.testing.assert_array_equal(p.A[rows], unit)
        assert np.all(p.b[rows] == 0.0)
        assert np.all(x[columns] == 0.0)
        plain = p.copy()
        plain.fixed = None
        reference = ActiveSetGuess().polish(plain, x)  # the full system's KKT point of the same QP
        assert reference is not None
        scale = max(1.0, float(np.abs(x).max()))
        np.testing.assert_allclose(x, reference, rtol=0, atol=1e-11 * scale)
        assert p.violation(x) < 1e-8


def test_a_new_hessian_array_in_the_same_problem_is_read_by_the_reduced_system() -> None:
    """The controller's problem object kept from tick to tick, its ``H`` replaced by a new array
    (another cost): the reduced KKT system copies the new ``H``, not the blocks of the old one —
    the answer is the new QP's optimum, the one the full system finds."""
    p = _pinned_problem(0)
    p.fixed = (np.array([5, 6, 7]), np.array([2, 3, 4]))
    guess = ActiveSetGuess(steps=50)
    assert guess.try_solve(p) is not None
    rng = np.random.default_rng(7)
    L = rng.normal(size=(p.n, p.n))
    p.H = L @ L.T + 3.0 * p.n * np.eye(p.n)
    x = guess.try_solve(p)
    plain = p.copy()
    plain.fixed = None
    reference = ActiveSetGuess(steps=50).try_solve(plain)
    assert x is not None and reference is not None
    np.testing.assert_allclose(x, reference, rtol=0, atol=1e-12 * max(1.0, float(np.abs(reference).max())))


@pytest.mark.parametrize("eliminated", [True, False])
def test_a_row_pinned_on_one_tick_and_opened_on_the_next_gets_its_multiplier_checked(eliminated: bool) -> None:
    """The problem object and its arrays kept from tick to tick, refilled in place (as the
    controller does), x2 eliminated or not: min ½|x|² − 2 x0 − 2 x1 with x2 = 0 and one row
    l ≤ x0 + x1 ≤ u. Pinned (l = u = 0) the row is active; opened to [−5, 5] its unconstrained
    optimum x0 + x1 = 4 lies inside, so the answer is (2, 2, 0), the row dropped — not the
    point on the row's old side (2.5, 2.5, 0), whose multiplier has the wrong sign."""
    lu = np.zeros(2)
    p = QpProblem(H=np.eye(3), g=np.array([-2.0, -2.0, 0.0]), A=np.array([[0.0, 0.0, 1.0]]), b=np.zeros(1),
                  C=np.array([[1.0, 1.0, 0.0]]), l=lu[:1], u=lu[1:], structure=5)
    if eliminated:
        p.fixed = (np.array([2]), np.array([0]))
    guess = ActiveSetGuess(steps=10)
    x = guess.try_solve(p)
    assert x is not None and list(guess.active) == [0]
    np.testing.assert_allclose(x, [0.0, 0.0, 0.0], atol=1e-12)
    lu[:] = [-5.0, 5.0]
    x = guess.try_solve(p)
    assert x is not None
    np.testing.assert_allclose(x, [2.0, 2.0, 0.0], atol=1e-12)
    assert len(guess.active) == 0


def _declared_box(n: int = 30) -> QpProblem:
    """min ½‖x − t‖² s.t. −1 ≤ x ≤ 1 (rows of C), refilled in place from tick to tick: a declaration
    closes some rows at 0 (``l = u = 0``: their variables held at zero, the rows dead)."""
    return QpProblem(H=np.eye(n), g=np.zeros(n), A=np.zeros((0, n)), b=np.zeros(0), C=np.eye(n),
                     l=np.full(n, -1.0), u=np.full(n, 1.0), structure=310)  # fmt: skip


def _tick(guess: ActiveSetGuess, p: QpProblem, target: np.ndarray, closed: tuple[int, ...] | None, dtype=np.int64):
    """Refill ``p`` for ``target`` with the rows ``closed`` at zero and declared (a new tuple, as
    ``ContactSet`` makes one per change), and return the guess's answer and its KKT solves."""
    p.g[...] = -target
    p.l[...], p.u[...] = -1.0, 1.0
    if closed is None:
        if p.fixed is not None:
            p.fixed = None
    else:
        p.l[list(closed)] = p.u[list(closed)] = 0.0
        if p.fixed is None or list(p.fixed[0]) != list(closed) or p.fixed[0].dtype != dtype:
            p.fixed = (np.array(closed, dtype=dtype), np.zeros(0, dtype=dtype), np.array(closed, dtype=dtype))
    before = guess.solves
    x = guess.try_solve(p)
    if x is not None:
        expected = np.clip(target, -1.0, 1.0)
        if closed is not None:
            expected[list(closed)] = 0.0
        np.testing.assert_array_equal(x, expected)
    return x, guess.solves - before


def test_at_a_declaration_change_the_guess_is_the_set_found_after_the_same_change_last_time() -> None:
    """A box QP whose declaration alternates as a walker's does (none, B, none, C, none, B), each
    phase with its own target: 23 coordinates beyond the box in B and C (24 solves from an empty
    set), none in the undeclared phase. A change has a budget of ``change_steps`` = 24 solves
    (enough), a tick without one ``steps`` = 12 (not enough); the second B change starts from the
    set the first found (1 solve) — C's change, from the same declaration, is told apart —
    and so does a B declared with int32 indices; after ``reset`` the changes are forgotten."""
    n = 30
    inside = np.full(n, 0.5)
    b_target, c_target = inside.copy(), inside.copy()
    b_target[7:30] = 3.0  # 23 rows at their upper limit
    c_target[5:28] = -3.0  # 23 rows at their lower limit
    p = _declared_box(n)
    guess = ActiveSetGuess()
    assert (guess.steps, guess.change_steps) == (12, 24)
    x, solves = _tick(guess, p, inside, None)
    assert x is not None and solves == 1
    x, solves = _tick(guess, p, b_target, (0, 1, 2))  # a change: 24 solves within its budget
    assert x is not None and solves == 24
    assert guess._views[0].shape[0] == n - 3 + 23  # (the closed rows' variables eliminated, their rows never active)
    x, solves = _tick(guess, p, inside, None)  # the change back: its set unknown yet, 24 exchanges away
    assert x is not None and solves == 24
    x, solves = _tick(guess, p, c_target, (0, 1, 2, 3, 4))
    assert x is not None and solves == 24
    x, solves = _tick(guess, p, inside, None)  # the change back from C: not B's
    assert x is not None and solves == 24
    x, solves = _tick(guess, p, b_target, (0, 1, 2), dtype=np.int32)  # B again: the set found last time
    assert x is not None and solves == 1
    x, solves = _tick(guess, p, inside, None)  # and back (the change B -> none was seen once)
    assert x is not None and solves == 1
    # A tick without a change has a budget of 12: B's 23 rows from an empty set are not reached.
    _tick(guess, p, inside, (0, 1, 2))  # (the change none -> B: its set recalled, then the search)
    guess._set_active(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool))
    x, solves = _tick(guess, p, b_target, (0, 1, 2))
    assert x is None and solves == 12
    # reset forgets the sets found after changes: none -> B takes its full search again.
    guess.reset()
    _tick(guess, p, inside, None)
    x, solves = _tick(guess, p, b_target, (0, 1, 2))
    assert x is not None and solves == 24


@pytest.mark.parametrize("closed_rows, expected", [(23, 24), (24, None)])
def test_a_change_s_search_is_bounded_by_change_steps(closed_rows: int, expected: int | None) -> None:
    """From an empty set, k rows to add take k + 1 solves: at a declaration change 23 rows are
    reached within the 24-solve budget, 24 rows are not (exactly 24 solves spent, no answer)."""
    n = 30
    target = np.full(n, 0.5)
    target[3 : 3 + closed_rows] = 3.0
    p = _declared_box(n)
    guess = ActiveSetGuess()
    _tick(guess, p, np.full(n, 0.5), None)
    x, solves = _tick(guess, p, target, (0, 1, 2))
    assert solves == 24
    assert (x is not None) == (expected is not None)


def test_more_than_32_declarations_and_changes_are_answered() -> None:
    """The memories of declarations and of changes are bounded (cleared at 32 entries): 40
    different declarations in a row (each a change never seen) are all answered exactly."""
    n = 12
    p = _declared_box(n)
    guess = ActiveSetGuess(steps=20)
    target = np.linspace(-3.0, 3.0, n)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)][:40]
    for pair in pairs:
        x, _ = _tick(guess, p, target, pair)
        assert x is not None
