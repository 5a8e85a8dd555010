"""The proxsuite backend: one persistent dense ProxQP, updated in place and warm-started each tick."""

from __future__ import annotations

import math
import time

import numpy as np

from giwbc.control.qp.active_set import ActiveSetGuess
from giwbc.control.qp.problem import USABLE, QpProblem, QpSolution, QpSolver, QpStatus
from giwbc.control.qp.proxsuite_build import load_proxsuite


class ProxsuiteSolver(QpSolver):
    """Persistent ``proxsuite.proxqp.dense.QP``, updated in place and warm-started every tick.

    Settings: ``eps_abs`` (default 1e-6), ``eps_rel`` (0), ``backend`` (``"PrimalDualLDLT"``,
    measured fastest on the G1 problem with warm starts, or ``"Automatic"``), plus any attribute
    of ``proxsuite.proxqp.Settings`` by name, and:

    * ``max_iter`` (default 10) and ``max_iter_in`` (default 10) — the **hard bound** of a tick.
      proxsuite 0.8 runs up to ``max_iter`` *outer* (proximal / BCL) iterations, each with up to
      ``max_iter_in`` *inner* semi-smooth Newton iterations (its default: 1500), and reports the
      inner ones in ``info.iter``: ``max_iter`` alone bounds nothing useful (a falling robot's QP
      ran 4734 inner iterations, 0.8 s, under ``max_iter=300``; an infeasible one 13 million,
      270 s, under proxsuite's defaults). Here ``max_iter`` is the budget of outer iterations of
      the whole tick, cold retry included, so a tick runs at most ``max_iter × (max_iter_in + 1)``
      inner ones (110: 2–5 ms on the G1 problem), plus at most ``3 · steps + 6 · polish_steps + 4``
      KKT solves (:class:`ActiveSetGuess`, ~50 µs each: the guess, then per proxsuite answer the
      polish, its recovery and the settle; ``steps + polish_steps`` on a tick whose polish
      succeeds). Measured need at ``eps_abs=1e-6``: ≤ 5 outer
      / 6 inner iterations warm (the balance replay), ≤ 10 / 46 cold from random states; the
      polish turns a nearly converged iterate into the exact optimum. Accurate offline solves
      (``eps_abs=1e-9``) want larger budgets.
    * ``retry_cold`` — when a warm-started solve fails, re-initialise and solve from scratch with
      the rest of the budget (warm starts far from the new solution occasionally end in a
      spurious infeasibility verdict).
    * ``active_set_guess`` (default True) — first try last tick's active set with one KKT solve,
      then up to ``steps − 1`` (11) one-row exchanges (:meth:`ActiveSetGuess.try_solve`);
      proxsuite runs only when no set reached so is provably optimal (0.3 % of the ticks of a
      recorded G1 walk, 7.6 % with the former all-at-once corrections).
    * ``polish`` (default True) — after proxsuite, solve the KKT system of the rows tight at its
      iterate, corrected into a provably optimal active set (:meth:`ActiveSetGuess.polish`;
      where that fails, :meth:`ActiveSetGuess.recover`: proxsuite can report success at a point
      off by more than the slack, whose tight rows are not the optimum's): the
      answer is then the exact optimum, computed deterministically. proxsuite alone is not
      bit-reproducible (its results differ by ~1e-14 with the memory layout of the process);
      polished answers are, its bits only deciding which side of ``max(10 eps_abs, 1e-5)`` a
      row's slack falls. Without the polish, proxsuite's ``check_duality_gap`` defaults to True
      (else a warm start can end on a non-optimal point reported solved).
    * ``deterministic`` (default True) — where the polish finds no provably optimal active set
      (degenerate or nearly infeasible problems, typically a falling robot), the answer is the
      KKT point of the rows tight at proxsuite's iterate (:meth:`ActiveSetGuess.settle`),
      accepted when it satisfies every constraint to ``max(eps_abs, 1e-7)``, whatever proxsuite's
      own verdict: proxsuite's last bits then only matter through which side of
      ``max(10 eps_abs, 1e-5)`` a row's slack falls. ``False``: proxsuite's own solution and
      verdict.
    """

    name = "proxsuite"

    def __init__(
        self,
        *,
        eps_abs: float = 1e-6,
        eps_rel: float = 0.0,
        max_iter: int = 10,
        max_iter_in: int = 10,
        backend: str = "PrimalDualLDLT",
        retry_cold: bool = True,
        active_set_guess: bool = True,
        polish: bool = True,
        deterministic: bool = True,
        **settings: object,
    ) -> None:
        proxsuite = load_proxsuite()  # its baseline build: bit-reproducible (proxsuite_build)

        if int(max_iter) < 1 or int(max_iter_in) < 1:
            raise ValueError(f"max_iter and max_iter_in must be >= 1, got {max_iter}, {max_iter_in}")
        unknown = sorted(key for key in settings if not hasattr(proxsuite.proxqp.Settings(), key))
        if unknown:  # (else the first solve would fail, tick after tick)
            raise ValueError(f"unknown proxsuite settings {unknown}")
        self.retry_cold = retry_cold
        self.max_iter = int(max_iter)
        self.max_iter_in = int(max_iter_in)
        self._kkt = ActiveSetGuess() if (active_set_guess or polish) else None
        self.guess = self._kkt if active_set_guess else None
        self._polish = bool(polish)
        self.deterministic = bool(deterministic)
        self._proxqp = proxsuite.proxqp
        self._settings = dict(eps_abs=eps_abs, eps_rel=eps_rel, max_iter=self.max_iter, max_iter_in=self.max_iter_in, verbose=False, **settings)
        self._backend = getattr(proxsuite.proxqp.dense.DenseBackend, backend)
        self.reset()
        out = proxsuite.proxqp.QPSolverOutput
        self._status = {
            out.PROXQP_SOLVED: QpStatus.SOLVED,
            out.PROXQP_SOLVED_CLOSEST_PRIMAL_FEASIBLE: QpStatus.INACCURATE,
            out.PROXQP_MAX_ITER_REACHED: QpStatus.MAX_ITER,
            out.PROXQP_PRIMAL_INFEASIBLE: QpStatus.PRIMAL_INFEASIBLE,
            out.PROXQP_DUAL_INFEASIBLE: QpStatus.DUAL_INFEASIBLE,
        }
        if not self._polish:
            # Without the polish nothing checks complementarity: a warm-started solve whose
            # limits moved can stop at once on a wrong point marked solved (measured: 27 of 40
            # small random QPs after l *= 1.02). proxsuite's duality-gap test catches those.
            self._settings.setdefault("check_duality_gap", True)

    def reset(self) -> None:
        self._qp = None
        self._structure = None
        self._problem = None
        self._token = -1
        self._rows = None
        if self._kkt is not None:
            self._kkt.reset()

    def _init(self, p: QpProblem) -> None:
        dense = self._proxqp.dense
        qp = dense.QP(p.n, p.n_eq, p.n_in, p.has_bounds, dense.HessianType.Dense, self._backend)
        for key, value in self._settings.items():
            setattr(qp.settings, key, value)
        qp.settings.initial_guess = self._proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
        if p.has_bounds:
            qp.init(p.H, p.g, p.A, p.b, p.C, p.l, p.u, p.lb, p.ub)
        else:
            qp.init(p.H, p.g, p.A, p.b, p.C, p.l, p.u)
        self._qp = qp

    def solve(self, problem: QpProblem) -> QpSolution:
        start = time.perf_counter()
        p = problem
        # Same problem object and structure token as last time: the hot path, no bookkeeping.
        cold = self._qp is None or p is not self._problem or p.structure != self._token
        guess = self.guess
        if guess is not None and not cold:
            x = guess.try_solve(p)
            if x is not None:
                return QpSolution(x, QpStatus.SOLVED, 0, self.name, "active-set guess", time.perf_counter() - start, guess.rows)
        if cold:
            key = (p.structure, p.n, p.n_eq, p.n_in, p.has_bounds)
            cold = self._qp is None or key != self._structure
        try:
            if cold:
                # First tick, new structure, or recovering from a failure: a cold init.
                self._init(p)
                self._structure = (p.structure, p.n, p.n_eq, p.n_in, p.has_bounds)
            elif p.lb is not None:
                self._qp.update(p.H, p.g, p.A, p.b, p.C, p.l, p.u, p.lb, p.ub)
            else:
                self._qp.update(p.H, p.g, p.A, p.b, p.C, p.l, p.u)
            self._qp.settings.max_iter = self.max_iter
            self._qp.solve()
        except Exception as error:  # proxsuite raises on malformed input; never inside the loop
            self.reset()
            return self._failure(p.n, QpStatus.FAILED, f"proxsuite error: {error}", start)
        self._problem, self._token = p, p.structure
        status, iterations, outer = self._status_of(self._qp.results)
        x, status = self._answer(p, status)
        left = self.max_iter - outer
        if x is None and self.retry_cold and not cold and left > 0:
            # A warm start from a far-away previous solution can make proxsuite stall or
            # report a spurious infeasibility: retry from scratch with the rest of the budget.
            try:
                self._init(p)
                self._qp.settings.max_iter = left
                self._qp.solve()
            except Exception as error:
                self.reset()
                return self._failure(p.n, QpStatus.FAILED, f"proxsuite error: {error}", start, iterations)
            status, more, _ = self._status_of(self._qp.results)
            iterations += more
            x, status = self._answer(p, status)
        if x is None:
            self.reset()  # do not warm-start from a failed solve
            if status in USABLE:  # proxsuite's point, but no feasible KKT point near it
                return self._failure(p.n, QpStatus.FAILED, f"proxsuite: {status.value}, but no KKT point near its iterate is feasible", start, iterations)
            return self._failure(p.n, status, f"proxsuite: {status.value}", start, iterations)
        return QpSolution(x, status, iterations, self.name, "", time.perf_counter() - start, self._rows)

    def _answer(self, p: QpProblem, status: QpStatus) -> tuple[np.ndarray | None, QpStatus]:
        """The tick's answer from proxsuite's results: polished (exact, deterministic); else,
        when ``deterministic``, settled (:meth:`ActiveSetGuess.settle`: the KKT point of the rows
        tight at proxsuite's iterate, whatever proxsuite's verdict, accepted if feasible); else
        proxsuite's own solution when usable; else None."""
        results = self._qp.results  # type: ignore[union-attr]
        kkt = self._kkt
        self._rows = None
        if kkt is not None and self._polish:
            # The iterate is accurate to eps_abs in the residuals, but far less in weakly
            # regularised directions (1e-9 of dual residual on a 1e-5 Hessian: 1e-4 in x):
            # rows within 1e-5 of a bound count as tight, the polish drops the wrong ones.
            eps = float(self._settings["eps_abs"])  # type: ignore[arg-type]
            slack = max(10.0 * eps, 1e-5)
            iterate = np.asarray(results.x)
            x = kkt.polish(p, iterate, slack=slack)
            if x is None:  # (an iterate off by more than slack, reported solved: ActiveSetGuess.recover)
                x = kkt.recover(p, iterate, slack=slack)
            if x is not None:
                self._rows = kkt.rows
                return x, QpStatus.SOLVED  # every KKT condition verified: the optimum
            if self.deterministic:
                x = kkt.settle(p, iterate, slack=slack, feasibility=max(eps, 1e-7))
                if x is None:
                    return None, status
                self._rows = kkt.rows
                return x, status if status in USABLE else QpStatus.INACCURATE
        if status not in USABLE:
            return None, status
        x = np.array(results.x)
        if kkt is not None:
            kkt.learn(p, x, results.z)
        return x, status

    def _status_of(self, results: object) -> tuple[QpStatus, int, int]:
        info = results.info  # type: ignore[attr-defined]
        status = self._status.get(info.status, QpStatus.FAILED)
        if status in USABLE:
            x = results.x  # type: ignore[attr-defined]
            if not math.isfinite(float(x @ x)):
                status = QpStatus.FAILED
        return status, int(info.iter), int(info.iter_ext)
