"""A walker's touch-down ticks: the contact just made (normal force capped at 0) is declared
fixed in the QP instead of a friction cone closed at its apex, and the active set found after
the same declaration change last time is the next guess — the exact optimum from a few KKT
solves, no backend, no force jump beyond the ramp."""

from __future__ import annotations

import numpy as np

from giwbc.control.qp import ActiveSetGuess, QpProblem, make_solver
from giwbc.locomotion import walker as walker_module
from giwbc.locomotion.simulation import simulate_walk


def test_touch_down_ticks_are_exact_answers_of_the_guess_without_a_force_jump(g1, monkeypatch) -> None:
    """A 3 s MuJoCo walk at 0.3 m/s (seed 0). At every touch-down tick the new contact's
    forces are eliminated (declared with its 17 friction rows, its motion rows kept: the foot
    still constrained) and exactly zero; at the tick after, its normal force lies within its
    ramp's cap ``activation · weight``. Both ticks are answered by the active-set guess (no
    backend), from the third touch-down on in at most 6 KKT solves (the set found after the same
    change one step earlier; measured 1-5, 8-14 and backend calls before), and the answer
    equals a fresh backend's polished optimum of the same QP without the declaration (1e-9)."""
    ticks: list[dict] = []
    original = walker_module.WalkingController.update

    def recording(self, q, v, t, forces=None):
        kkt = self.wbc.solver._kkt
        before = kkt.solves
        result = original(self, q, v, t, forces)
        slots = self.wbc.contact_set.slot_list
        ticks.append({
            "steps": self.state.steps, "solves": kkt.solves - before, "message": result.message,
            "problem": self.wbc.problem.copy(), "x": np.concatenate([result.qdd, result.forces]),
            "slots": [(slot.activation, slot.engaged, slot.columns, slot.motion_rows, slot.friction_rows, slot.ramp_force) for slot in slots],
        })
        return result

    monkeypatch.setattr(walker_module.WalkingController, "update", recording)
    run = simulate_walk(g1, (0.3, 0.0, 0.0), 3.0, seed=0)
    monkeypatch.undo()
    assert not run.fell and run.wbc_failures == 0 and run.steps >= 4
    downs = [i for i in range(1, len(ticks)) if ticks[i]["steps"] != ticks[i - 1]["steps"]]
    assert len(downs) >= 4
    checked = 0
    for number, i in enumerate(downs):
        down, after = ticks[i], ticks[i + 1]
        made = [k for k, (activation, engaged, *_rest) in enumerate(down["slots"]) if engaged and activation == 0.0]
        assert len(made) == 1
        k = made[0]
        _, _, columns, motion_rows, friction_rows, ramp_force = down["slots"][k]
        p: QpProblem = down["problem"]
        assert p.fixed is not None and len(p.fixed) == 3
        np.testing.assert_array_equal(p.fixed[0], np.arange(columns.start, columns.stop))
        assert len(p.fixed[1]) == 0  # (its motion rows are not unit rows: they hold the foot)
        np.testing.assert_array_equal(p.fixed[2], np.arange(friction_rows.start, friction_rows.stop))
        assert np.any(p.A[motion_rows, : columns.start] != 0.0)
        assert np.all(down["x"][columns] == 0.0)
        activation = after["slots"][k][0]
        assert 0.0 < activation < 0.5
        normal = after["x"][columns.start + 2]  # (a surface contact: the wrench, f_z third)
        assert -1e-9 <= normal <= activation * ramp_force + 1e-9
        for tick in (down, after):
            assert tick["message"] == "active-set guess"
            if number >= 2:
                assert tick["solves"] <= 6
            plain = tick["problem"].copy()
            plain.fixed = None
            solution = make_solver("proxsuite").solve(plain)
            assert solution.ok
            scale = max(1.0, float(np.abs(solution.x).max()))
            np.testing.assert_allclose(tick["x"], solution.x, rtol=0, atol=1e-9 * scale)
            checked += 1
    assert checked >= 8


def test_a_cone_closed_at_zero_declared_fixed_gives_the_optimum_of_the_undeclared_problem() -> None:
    """A small QP with a 3-variable force ``f`` inside a friction pyramid whose normal bound is 0
    (``0 ≤ f_z ≤ 0``, ``|f_x|, |f_y| ≤ μ f_z``: only ``f = 0``), coupled to 3 other variables
    through ``H``, one equality row and a two-sided row: declared ``(f, no equality rows, the
    pyramid's rows)`` the guess answers from a system without ``f`` (no pyramid row ever in its
    active set, even when the first guess holds them), the same optimum as the problem without the
    declaration (a backend's on the QP with ``f = 0`` substituted), ``f`` exactly 0.
    Without the declaration the pyramid's 5 faces meet at ``f = 0``: a degenerate vertex."""
    rng = np.random.default_rng(3)
    n, mu = 6, 0.7
    for trial in range(10):
        L = rng.normal(size=(n, n))
        H = L @ L.T + np.eye(n)
        C = np.zeros((7, n))
        C[:2] = rng.normal(size=(2, n))  # two general rows
        pyramid = np.array([[1.0, 0.0, -mu], [-1.0, 0.0, -mu], [0.0, 1.0, -mu], [0.0, -1.0, -mu], [0.0, 0.0, 1.0]])
        C[2:, 3:] = pyramid
        l = np.concatenate([[-1.0, -1.0], np.full(4, -np.inf), [0.0]])
        u = np.concatenate([[1.0, 1.0], np.zeros(4), [0.0]])
        A = rng.normal(size=(1, n))
        p = QpProblem(H=H, g=rng.normal(size=n) * 5.0, A=A, b=rng.normal(size=1), C=C, l=l, u=u, structure=900 + trial)
        declared = p.copy()
        declared.fixed = (np.array([3, 4, 5]), np.zeros(0, dtype=np.int64), np.arange(2, 7))
        guess = ActiveSetGuess(steps=30)
        guess._prepare(declared)
        guess._set_active(np.array([0, 2, 3, 6]), np.array([True, False, False, True]))  # pyramid rows in the first guess
        guess._reduce(declared)
        x = guess.try_solve(declared)
        assert x is not None
        assert np.all(x[3:] == 0.0)
        assert not np.any(guess.active >= 2)
        assert guess._views[0].shape[0] == 3 + 1 + len(guess.active)  # (f and the pyramid gone)
        # The reference: f = 0 substituted (the only f the pyramid allows), a regular QP in 3 variables.
        substituted = QpProblem(H=H[:3, :3].copy(), g=p.g[:3].copy(), A=A[:, :3].copy(), b=p.b.copy(), C=C[:2, :3].copy(), l=l[:2].copy(), u=u[:2].copy())
        reference = make_solver("proxsuite").solve(substituted)
        assert reference.ok and reference.message != "active-set guess"
        np.testing.assert_allclose(x[:3], reference.x, rtol=0, atol=1e-9 * max(1.0, float(np.abs(reference.x).max())))
        assert p.violation(x) < 1e-9
