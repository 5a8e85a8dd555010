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
