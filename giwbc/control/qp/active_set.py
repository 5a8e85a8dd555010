"""The active-set guess: exact, deterministic QP answers from a guessed active set (see :class:`ActiveSetGuess`)."""

from __future__ import annotations

import math

import numpy as np

from giwbc.control.qp.kernels import kkt_check, kkt_fill, warm
from giwbc.control.qp.problem import QpProblem


class ActiveSetGuess:
    """Exact solutions of the QP from a guess of its active set, checked for optimality.

    One dense KKT solve (LAPACK ``dgesv``) of ``[[H, Aᵀ, C_aᵀ], [A, 0, 0], [C_a, 0, 0]]`` with
    ``C_a`` the inequality rows of the active set (variable bounds count as identity rows after
    the rows of ``C``); the candidate is accepted when it satisfies every inequality (to
    ``tolerance``), the equalities (to ``tolerance`` too: an ill-conditioned system is not
    trusted) and the multipliers of the active rows have the right signs — then all KKT
    conditions hold and, the QP being convex, the candidate *is* its optimum (to machine
    precision, tighter than an iterative solver). When it is not, the active set is corrected
    and solved again, up to a bound of KKT solves.

    Two uses:

    * :meth:`try_solve` — *before* the backend, with last tick's active set: the active set of a
      balance controller rarely changes from one tick to the next, so most ticks end here; when
      it did change, up to ``steps − 1`` one-row exchanges (drop the row of worst multiplier
      sign, add the most violated row: a conservative primal-dual active-set search, with cycle
      detection) usually reach the new optimum — a walking controller's friction rows toggle as
      the CoP reaches a sole's edge, its contacts switch — at ~25 µs a solve on the G1 problem
      against ~400 µs for the backend and its polish;
    * :meth:`polish` — *after* the backend, from the rows tight at its (approximate) solution,
      with ``polish_steps`` regularised KKT solves, each correction adding every violated row and
      dropping every wrong-sign one (:meth:`_iterate`; the backend's tight rows are close to the
      optimum's): the answer becomes the exact optimum computed
      by the same deterministic KKT solve (:meth:`recover` where the polish fails, the
      backend's point being off by more than its slack); :meth:`settle` is the fallback when no provably
      optimal active set is found (degenerate, nearly infeasible problems). This is what makes
      the proxsuite backend bit-reproducible: proxsuite's own iterates differ in the last bits
      from run to run (its Eigen kernels are vectorised differently depending on the alignment
      of its internal buffers), while the numpy/LAPACK operations here give identical results
      whatever the alignment of their operands (measured, and tested), and the backend's bits
      only enter through discrete decisions (which side of a threshold a row's slack falls).
      The active set is kept sorted, so the KKT system of a given active set is always the same.

    Variables the problem declares held at zero (``QpProblem.fixed``: a broken contact's pinned
    wrench in single support) are eliminated with their equality rows: the KKT system is that
    many rows and columns smaller (G1 single support: 12 of ~67, its LU ~30 % cheaper) and the
    answer the same optimum, those variables exactly zero. Inequality rows the declaration names
    (rows of fixed variables only, e.g. a just-made contact's friction cone closed at zero force)
    never enter the active set: at those variables' zero they are a degenerate vertex (16 cone
    faces meeting at one point), whose rows in a KKT system are zero.

    When the declaration changes (a contact made or broken), the guess is the active set found
    the last time the same change happened, when there was one: last tick's set is then often
    many exchanges away (at a touch-down's second tick, the new contact's cone faces and the
    stance contact's own move together), and a walker repeats its changes step after step.

    The active set found (by either) is the next tick's guess. ``hits``/``tries`` count the
    guesses, ``polished``/``polish_failures`` the polishes, ``solves`` the KKT solves (all
    uses): diagnostics, not reset by
    :meth:`reset`. :attr:`rows` holds ``[A; C] x`` of the last answer (the controller reads its
    torques there).
    """

    def __init__(self, tolerance: float = 1e-8, steps: int = 12, polish_steps: int = 4, threshold: float = 1e-10, change_steps: int = 24) -> None:
        from scipy.linalg import lapack

        self.steps = int(steps)
        self.change_steps = int(change_steps)  # the search's budget at a declaration change
        self.polish_steps = int(polish_steps)
        self.tolerance = float(tolerance)
        self.threshold = float(threshold)  # |multiplier| above which a backend's row counts as active
        self._gesv = lapack.dgesv
        self._layout: tuple | None = None
        self._prepared: QpProblem | None = None
        self._prepared_structure = -1
        self._prepared_arrays: tuple = (None, None, None, None)
        self._fixed_source: tuple | None = None
        self._keep: np.ndarray | None = None  # the variables the KKT system keeps (None: all)
        self._dead: np.ndarray | None = None  # mask of the inequality rows of fixed variables only (never active)
        self._reductions: dict[tuple, tuple] = {}  # fixed declaration -> what _reduce derives from it
        self._fixed_key: tuple = ()  # the declaration of _fixed_source, as a key
        self._changes: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}  # declaration change -> set found after it
        self._change: tuple | None = None  # the change of the last tick's declaration (its set is stored next tick)
        self.hits = 0
        self.tries = 0
        self.polished = 0
        self.polish_failures = 0
        self.solves = 0
        self.reset()
        warm()  # (the compiled KKT kernels, once a process: not in a control loop's first ticks)

    def reset(self) -> None:
        """Forget the active set (the next :meth:`try_solve` starts from an empty one) and the
        sets found after declaration changes."""
        self._set_active(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool))
        self._changes = {}
        self._change = None

    def _set_active(self, active: np.ndarray, upper: np.ndarray) -> None:
        order = np.argsort(active, kind="stable")
        self.active = np.ascontiguousarray(active[order], dtype=np.int64)
        self.upper = np.ascontiguousarray(upper[order], dtype=bool)
        self._stale = True  # per-active-set vectors to recompute

    def _set_live(self, active: np.ndarray, upper: np.ndarray) -> None:
        """:meth:`_set_active` without the rows the problem's declaration holds dead."""
        dead = self._dead
        if dead is not None and len(active):
            live = ~dead[active]
            active, upper = active[live], upper[live]
        self._set_active(active, upper)

    @property
    def rows(self) -> np.ndarray:
        """``[A; C; I] x`` of the last answer (a view, overwritten by the next solve)."""
        return self._r

    def learn(self, problem: QpProblem, x: np.ndarray, z: np.ndarray) -> None:
        """Active set of a solution from its inequality multipliers ``z`` (rows of ``C``, then
        the variable bounds; positive: upper bound). The problem's layout is prepared first: a
        new layout would otherwise discard the set at the next :meth:`try_solve`."""
        self._prepare(problem)
        active = np.flatnonzero(np.abs(z) > self.threshold)
        self._set_live(active, z[active] > 0)

    # --- per-tick preparation --------------------------------------------------------------------
    def _prepare(self, p: QpProblem) -> None:
        """Stacked ``[A; C; I]`` rows and their bounds for this tick (views when the problem's
        ``A`` and ``C`` are adjacent in one buffer, as the controller lays them out).
        ``ValueError`` for a gradient or Hessian of the wrong shape (the compiled KKT assembly
        reads them unchecked)."""
        if p.g.shape != (p.n,) or p.H.shape != (p.n, p.n):
            raise ValueError(f"QP g has shape {p.g.shape} and H {p.H.shape}, expected ({p.n},) and ({p.n}, {p.n})")
        arrays = self._prepared_arrays
        if self._change is not None:  # the set found at the tick after a declaration change
            if len(self._changes) >= 32:
                self._changes = {}  # (a bound on the memory; a walker repeats a handful of changes)
            self._changes[self._change] = (self.active, self.upper)
            self._change = None
        if p is self._prepared and p.A is arrays[0] and p.C is arrays[1] and p.l is arrays[2] and p.u is arrays[3] and p.structure == self._prepared_structure:
            # The same problem and arrays as last time (the controller's, refilled every tick).
            if p.fixed is not self._fixed_source:
                self._recall(p.fixed)
                self._reduce(p)
            self._eq_limits[...] = p.b  # (slice writes: np.copyto without its dispatch, ~0.3 µs a call)
            pair = self._lu_source[2]
            if pair is not None:
                self._in_limits[...] = pair
            else:
                self._in_limits[0] = p.l
                self._in_limits[1] = p.u
            if not self._adjacent:
                self._fill_rows(p)
            return
        n, ne, ni = p.n, p.n_eq, p.n_in
        bounds = p.lb is not None
        key = (n, ne, ni, bounds)
        if key != self._layout:
            m = ni + (n if bounds else 0)  # inequality rows, bounds included
            self._rows = None  # the guess's own copy of [A; C; I], made when a problem needs it
            self._m = m
            self._limits = np.zeros(2 * (ne + m))  # [lower; upper] limits of [A; C; I] x
            self._lo = self._limits[: ne + m]  # (equality rows: b in both)
            self._hi = self._limits[ne + m :]
            pair = self._limits.reshape(2, ne + m)
            self._eq_limits = pair[:, :ne]  # (2, ne) view: lower and upper limits of the equalities
            self._in_limits = pair[:, ne : ne + ni]
            self._r = np.zeros(ne + m)  # [A; C; I] x
            self._check = np.zeros(2 * (ne + m) + m)  # violations (both sides) and signed multipliers
            self._kkt: dict[tuple[int, int, int], tuple] = {}
            self._changes = {}  # (row indices of another layout)
            self._reductions = {}
            self._layout = key
            self._source = (None, None)
            self._lu_source = (None, None, None)
            self._set_active(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool))
        # Decided for every new problem, not once per layout: a problem of the same size whose A
        # and C are separate arrays (a copy) must not be read through a view spanning both.
        self._adjacent = (
            not bounds
            and ne > 0
            and p.A.flags.c_contiguous
            and p.C.flags.c_contiguous
            and p.A.ctypes.data + p.A.nbytes == p.C.ctypes.data
        )
        if self._adjacent:
            if self._source[0] is not p.A:  # a view spanning A and C (they are adjacent)
                self._source = (p.A, np.lib.stride_tricks.as_strided(p.A, shape=(ne + ni, n), strides=p.A.strides, writeable=False))
            self._stack = self._source[1]
        else:
            if self._rows is None:
                self._rows = np.zeros((ne + self._m, n))
                if bounds:
                    self._rows[ne + ni :] = np.eye(n)
            self._stack = self._rows
            self._fill_rows(p)
        np.copyto(self._eq_limits, p.b)
        l, u = p.l, p.u
        source = self._lu_source
        if source[0] is not l or source[1] is not u:  # a (2, n_in) view when l and u are adjacent (the controller's)
            adjacent = ni and l.flags.c_contiguous and u.flags.c_contiguous and u.ctypes.data - l.ctypes.data == l.nbytes
            pair = np.lib.stride_tricks.as_strided(l, shape=(2, ni), strides=(l.nbytes, l.itemsize), writeable=False) if adjacent else None
            source = self._lu_source = (l, u, pair)
        if source[2] is not None:
            self._in_limits[...] = source[2]
        else:
            self._in_limits[0] = l
            self._in_limits[1] = u
        self._prepared, self._prepared_structure = p, p.structure
        self._prepared_arrays = (p.A, p.C, p.l, p.u)
        self._reduce(p)

    def _recall(self, fixed: tuple | None) -> None:
        """A declaration change: its active set of last time as the guess, when there is one."""
        change = (self._fixed_key, _signature(fixed))
        known = self._changes.get(change)
        if known is not None:
            self._set_active(*known)
        self._change = change

    def _reduce(self, p: QpProblem) -> None:
        """The variables and equality rows the KKT system keeps: all but ``p.fixed``'s (when the
        fixed variables have no finite bounds: a bound row of one would be a zero row)."""
        self._fixed_source = fixed = p.fixed
        self._fixed_key = _signature(fixed)
        self._stale = True
        n, ne = p.n, p.n_eq
        if fixed is not None and p.lb is not None:
            if np.isfinite(p.lb[fixed[0]]).any() or np.isfinite(p.ub[fixed[0]]).any():  # type: ignore[index]
                fixed = None
        key = self._fixed_key if fixed is not None else ()
        reduction = self._reductions.get(key)
        if reduction is None:  # (a walker alternates between a few declarations: derived once each)
            if len(self._reductions) >= 32:
                self._reductions = {}
            reduction = self._reductions[key] = self._reduction(fixed, n, ne)
        self._keep, self._keep_eq, self._n_keep, self._ne_keep, self._dead, self._columns = reduction
        if self._dead is not None:
            self._set_live(self.active, self.upper)  # (last tick's set may hold them)

    def _reduction(self, fixed: tuple | None, n: int, ne: int) -> tuple:
        """What :meth:`_reduce` keeps of a declaration: the kept variables and equality rows,
        their counts, the mask of dead rows, the kept columns (all when none is fixed)."""
        if fixed is None or not len(fixed[0]):
            return None, np.arange(ne), n, ne, None, np.arange(n)
        keep = np.ones(n, dtype=bool)
        keep[fixed[0]] = False
        keep_eq = np.ones(ne, dtype=bool)
        keep_eq[fixed[1]] = False
        kept, kept_eq = np.flatnonzero(keep), np.flatnonzero(keep_eq)
        dead = None
        if len(fixed) > 2 and len(fixed[2]):
            dead = np.zeros(self._m, dtype=bool)
            dead[fixed[2]] = True
        return kept, kept_eq, len(kept), len(kept_eq), dead, kept

    def _fill_rows(self, p: QpProblem) -> None:
        """Copy ``A``, ``C`` and the bounds into the guess's own stacked buffers."""
        ne, ni = p.n_eq, p.n_in
        rows = self._rows
        rows[:ne] = p.A  # type: ignore[index]
        rows[ne : ne + ni] = p.C  # type: ignore[index]
        if p.lb is not None:
            self._lo[ne + ni :] = p.lb
            self._hi[ne + ni :] = p.ub

    def _refresh_active(self, p: QpProblem) -> None:
        """Vectors of the current active set (stacked row indices, right-hand-side indices,
        signs) and the views of its KKT buffers."""
        ne = p.n_eq
        n, ne_kept, keep_eq = self._n_keep, self._ne_keep, self._keep_eq
        active, upper = self.active, self.upper
        k = len(active)
        rows_a = self._active_rows = ne + active
        self._eq_rows = np.concatenate((keep_eq, rows_a))
        # The right-hand side of [A; C_a]: b, then the active bound of each row, from _limits.
        self._rhs_index = np.concatenate((keep_eq, rows_a + len(self._lo) * upper))
        # Multiplier signs, negated: − at an upper bound, + at a lower one; _solve_active drops
        # them (0) for the rows this tick's limits pin (l = u), deriving the signs per solve.
        self._sign_open = 1.0 - 2.0 * upper
        key = (k, n, ne_kept)
        if key not in self._kkt:
            size = n + ne_kept + k
            K = np.zeros((size, size))
            self._kkt[key] = (K, np.zeros(size), K.T, n)
        self._views = self._kkt[key]
        self._stale = False

    # --- the solve ---------------------------------------------------------------------------------
    def try_solve(self, p: QpProblem) -> np.ndarray | None:
        """The optimum if last tick's active set — or one reached from it by up to ``steps − 1``
        single-row primal-dual exchanges (:meth:`_search`; ``change_steps − 1`` at a change of
        the problem's ``fixed`` declaration, a contact made or broken: a rare tick, whose set
        may be further away, and the backend's answer costs as much as a dozen solves) — is
        provably optimal; else None (run the backend)."""
        self.tries += 1
        self._prepare(p)
        x = self._search(p, self.steps if self._change is None else max(self.steps, self.change_steps))
        if x is not None:
            self.hits += 1
        return x

    def polish(self, p: QpProblem, x: np.ndarray, slack: float = 1e-5) -> np.ndarray | None:
        """The exact optimum from an approximate solution ``x`` (a backend's): the rows within
        ``slack`` of a bound at ``x`` are the first active set, corrected by up to
        ``polish_steps − 1`` active-set updates (a row tight at ``x`` but inactive at the
        optimum has a wrong-sign multiplier and is dropped); None when no provably optimal
        active set is found (an infeasible or degenerate problem). The answer depends on ``x``
        only through which side of ``slack`` each row's slack falls — not on the backend's
        multipliers, which are far less reproducible near degenerate vertices."""
        self._tight(p, x, slack)
        # Rows tight at an approximate point are often linearly dependent (several faces of a
        # wrench cone at one vertex): every polish solve is regularised.
        x = self._iterate(p, self.polish_steps, regularized=True)
        if x is None:
            self.polish_failures += 1
        else:
            self.polished += 1
        return x

    def recover(self, p: QpProblem, x: np.ndarray, slack: float = 1e-5) -> np.ndarray | None:
        """The exact optimum where :meth:`polish` found none from ``x``, or None: the search of
        :meth:`try_solve` (one row each way per KKT solve, up to ``steps`` solves) from the rows
        within ``slack`` of a bound at ``x``, then the polish from the rows within ``slack / 10``
        and within ``10 slack`` (``polish_steps`` solves each). A backend may stop, reporting
        success, at a point off by more than ``slack`` in weakly conditioned directions: few or
        no rows are tight there, or one too many, and the polish's all-at-once corrections land
        on a singular set (measured: 6 of 1000 small random QPs, proxsuite at ``eps_abs=1e-6``).
        Like the polish, it depends on ``x`` only through which side of each threshold a row's
        slack falls."""
        self._tight(p, x, slack)
        y = self._search(p, self.steps)
        for other in (0.1 * slack, 10.0 * slack):
            if y is not None:
                break
            self._tight(p, x, other)
            y = self._iterate(p, self.polish_steps, regularized=True)
        return y

    def settle(self, p: QpProblem, x: np.ndarray, slack: float = 1e-5, feasibility: float = 1e-6) -> np.ndarray | None:
        """A point computed from ``x`` (an approximate solution, e.g. a backend's) through
        discrete decisions only: the rows within ``slack`` of a bound at ``x`` become the
        active set, and the answer is the KKT solution of that set — the optimum of the QP with
        those rows as equalities, the QP's own optimum when the set is right — if it satisfies
        every constraint to ``feasibility``; else None. Multiplier signs are not checked: where
        :meth:`polish` found no provably optimal active set (degenerate or nearly infeasible
        problems), this is a point within the backend's accuracy whose bits depend on ``x``
        only through which side of ``slack`` each row's slack falls."""
        active = self._tight(p, x, slack)
        for regularize in (False, True):
            y = self._solve_active(p, regularize, optimal=False, tol=feasibility)
            if y is not None:
                return y  # type: ignore[return-value]
        return None

    def _tight(self, p: QpProblem, x: np.ndarray, slack: float) -> np.ndarray:
        """Make the rows within ``slack`` of a bound at ``x`` the active set (sorted)."""
        self._prepare(p)
        ne = p.n_eq
        r = self._r
        np.dot(self._stack, np.asarray(x, dtype=float), out=r)
        above = (self._hi[ne:] - r[ne:]) <= slack
        below = (r[ne:] - self._lo[ne:]) <= slack
        active = np.flatnonzero(above | below)
        self._set_live(active, above[active])
        return self.active

    def _iterate(self, p: QpProblem, steps: int, regularized: bool = False) -> np.ndarray | None:
        """Up to ``steps`` KKT solves (each correction or regularised re-solve is one);
        ``regularized``: every solve regularised (see :meth:`_solve_active`)."""
        regularize = regularized
        for _ in range(steps):
            x = self._solve_active(p, regularize)
            if x is None:
                if regularize:
                    return None
                regularize = True  # singular: once more, regularised, with the same active set
            elif x is False:
                regularize = regularized
            else:
                return x
        return None

    def _search(self, p: QpProblem, steps: int) -> np.ndarray | None:
        """Up to ``steps`` KKT solves from the current active set, each correction exchanging at
        most one row each way (``single`` in :meth:`_solve_active`): the row whose multiplier has
        the worst sign leaves, the most violated inactive row joins. From last tick's set the
        optimum is usually a row or two away (a friction face toggled by a CoP at a sole's edge,
        a torque limit reached), and the all-at-once update of :meth:`_iterate` overshoots there:
        adding every violated row and dropping every wrong-sign one at once often lands on a
        set that is singular or as wrong as the first. A singular set is solved again
        regularised, and the search stays regularised from then on; a set that fails even so
        loses, once, its rows whose active limit is infinite (:meth:`_drop_unbounded`). None
        when the budget is spent, a set comes back (a cycle: the exchanges would repeat), or a
        regularised solve fails."""
        seen: set[tuple[bytes, bytes]] = set()
        # The first set is keyed only when the search goes on (most ticks end at the first
        # solve); _set_active replaces the arrays, never writes into them.
        first: tuple[np.ndarray, np.ndarray] | None = (self.active, self.upper)
        regularize = again = unbounded = False
        for step in range(steps):
            if not again and step:  # (a singular set solved again, regularised, is not a cycle)
                if first is not None:
                    seen.add((first[0].tobytes(), first[1].tobytes()))
                    first = None
                key = (self.active.tobytes(), self.upper.tobytes())
                if key in seen:
                    return None
                seen.add(key)
            again = False
            x = self._solve_active(p, regularize, single=True)
            if x is None:
                if not regularize:
                    regularize = again = True  # singular: once more, regularised, with the same active set
                elif not unbounded and self._drop_unbounded(p.n_eq):
                    unbounded = True  # (last tick's set held rows whose active limit is gone)
                else:
                    return None
            elif x is not False:
                return x
            # (after a regularised solve the search stays regularised: the rows that made the
            # set singular are usually still in it, and an unregularised solve would fail first)
        return None

    def _drop_unbounded(self, ne: int) -> bool:
        """Drop the active rows whose limit on their active side is infinite (a row at ``l = u``
        last tick whose limits opened, e.g. a contact force bound at the start of its ramp):
        their KKT system has an infinite right-hand side. True when some were dropped."""
        active, upper = self.active, self.upper
        finite = np.isfinite(np.where(upper, self._hi[ne + active], self._lo[ne + active]))
        if finite.all():
            return False
        self._set_active(active[finite], upper[finite])
        return True

    def _solve_active(self, p: QpProblem, regularize: bool = False, optimal: bool = True, tol: float | None = None, single: bool = False) -> np.ndarray | None | bool:
        """KKT solve with the current active set: the optimum, ``False`` after correcting the
        active set, or None (singular or ill-conditioned system: give up). ``optimal=False``:
        no multiplier check and no correction (a feasible point of the active set or None).
        ``single``: the correction exchanges one row each way (see :meth:`_search`) instead of
        adding every violated row and dropping every wrong-sign one.

        ``regularize``: ``−δ I`` in the multiplier block, for a singular system (linearly
        dependent rows: a degenerate vertex, e.g. several faces of a contact wrench cone meeting
        at an edge, or the zeroed motion rows of a broken contact): dependent rows then share
        their multiplier, and the candidate violates them by ``δ |λ|`` (δ = 1e-4 · tolerance),
        well inside the tolerance it is checked against.
        """
        self.solves += 1
        if self._stale:
            self._refresh_active(p)
        k = len(self.active)
        stack = self._stack
        keep = self._keep
        K, rhs, KT, n = self._views
        # K is overwritten by the factorisation: the kernel writes every block again.
        kkt_fill(K, rhs, p.H, p.g, stack, self._columns, self._eq_rows, self._limits, self._rhs_index,
                 -1e-4 * self.tolerance if regularize else 0.0)
        # K is symmetric: its transpose is a Fortran-ordered view LAPACK factorises in place.
        # (Eliminating the diagonal force block first makes the LU 12 rows smaller, 25 → 19 µs,
        # but costs eight more numpy calls than it saves: measured slower.)
        _, _, solution, info = self._gesv(KT, rhs, overwrite_a=1, overwrite_b=0)
        if info != 0:
            return None
        if keep is None:
            x = solution[:n]
        else:
            x = np.zeros(p.n)
            x.put(keep, solution[:n])
        multipliers = solution[n + self._ne_keep :]  # of the active inequality rows
        ne = p.n_eq  # (the checks below are on every row)
        tol = self.tolerance if tol is None else tol
        r, check = self._r, self._check
        rows = len(r)
        stack.dot(x, out=r)
        # The signs from this tick's limits (in the kernel): a row pinned (l = u) last tick may be
        # open now in the same problem refilled in place, with the same active set (no refresh).
        worst = kkt_check(r, self._lo, self._hi, check, self._active_rows, self._sign_open, multipliers, optimal and k > 0)
        if not optimal:
            k = 0
        if worst <= tol:
            return x
        if not math.isfinite(worst) or (ne and max(check[:ne].max(), check[rows : rows + ne].max()) > tol):
            return None  # not finite, or the equalities do not hold: do not trust this system
        if not optimal:
            return None
        if single:
            self._exchange(ne, rows, k, tol)
            return False
        # Primal-dual active-set update: drop the wrong-sign rows, add the violated ones.
        keep = check[2 * rows : 2 * rows + k] <= tol
        violated = check[: 2 * rows].reshape(2, rows)[:, ne:] > tol  # rows: above, below
        violated[:, self.active] = False  # an active row stays (regularised solves bend them slightly)
        up = np.flatnonzero(violated[0])
        down = np.flatnonzero(violated[1])
        self._set_active(
            np.concatenate([self.active[keep], up, down]),
            np.concatenate([self.upper[keep], np.ones(len(up), dtype=bool), np.zeros(len(down), dtype=bool)]),
        )
        return False

    def _exchange(self, ne: int, rows: int, k: int, tol: float) -> None:
        """One row out, one row in: the active row whose multiplier has the worst sign (beyond
        ``tol``) is dropped, the inactive row violated most (beyond ``tol``; its upper side on a
        tie) is added — from the check of the last :meth:`_solve_active`, whose violations (a
        scratch buffer, written again by the next solve) it masks in place: the equality rows
        and the active rows (regularised solves bend those slightly) cannot be added. The set
        stays sorted by a splice at the added row's place (no re-sort: it is the same array)."""
        check = self._check
        active, upper = self.active, self.upper
        if k:
            signed = check[2 * rows : 2 * rows + k]
            worst = int(signed.argmax())
            if signed[worst] > tol:
                active = np.concatenate((active[:worst], active[worst + 1 :]))
                upper = np.concatenate((upper[:worst], upper[worst + 1 :]))
        violation = check[: 2 * rows]  # above, then below, every row: the first maximum is the
        violation[:ne] = -math.inf  # same (side, row) as in the (2, rows − ne) block of the inequalities
        violation[rows : rows + ne] = -math.inf
        violation[ne + self.active] = -math.inf
        violation[rows + ne + self.active] = -math.inf
        best = int(violation.argmax())
        if violation[best] > tol:
            side, row = divmod(best, rows)
            row -= ne
            at = int(active.searchsorted(row))
            active = np.concatenate((active[:at], (row,), active[at:]))
            upper = np.concatenate((upper[:at], (side == 0,), upper[at:]))
        self.active, self.upper = active, upper
        self._stale = True


def _signature(fixed: tuple | None) -> tuple[bytes, ...]:
    """A ``QpProblem.fixed`` declaration as a dictionary key."""
    return () if fixed is None else tuple(np.asarray(part, dtype=np.int64).tobytes() for part in fixed)
