"""The torque-level whole-body controller: an inverse-dynamics QP per tick.

Decision variables ``x = [q̈ (nv), f (contact force variables)]``; the joint torques are recovered
from the equation of motion ``M q̈ + h = Sᵀ τ + Σ Jᵀ Φ f`` (reduced formulation: only the
``n_base`` unactuated rows are equality constraints). The QP::

    min  Σ_tasks ‖J q̈ − (ẍ* − J̇ v)‖²_W + ‖f − f_ref‖²_Wf + ε ‖q̈‖²
    s.t. M_b q̈ − (JᵀΦ)_b f = −h_b                       floating-base rows of the dynamics
         J_c q̈ = −J̇_c v − Kp e − Kd J_c v                each active contact (6 rows, contact frame)
         F_c f_c ∈ [l_c, u_c]                            friction cone / pyramids, normal-force bounds
         τ_min − h_j ≤ M_j q̈ − (JᵀΦ)_j f ≤ τ_max − h_j   torque limits (joints with a finite limit)
         q̈_min ≤ q̈_j ≤ q̈_max                            optional joint position/velocity limits

Every matrix is preallocated when the *structure* (contacts, limits) changes and filled by
slicing each tick; constant blocks (friction rows, posture selection, regularisation) are written
once. :meth:`WholeBodyController.build` returns the :class:`~giwbc.control.qp.QpProblem`,
:meth:`WholeBodyController.solve` solves it, :meth:`WholeBodyController.update` does both and
returns a :class:`WbcResult` — it never raises on a numerical failure or a non-finite state: the
result then carries a fallback command and a status, and the controller counts the failure.

The solver backends (:mod:`giwbc.control.qp`) are persistent and warm-started; in front of them,
one KKT solve with the previous tick's active set answers most ticks exactly
(:class:`~giwbc.control.qp.ActiveSetGuess`; the backend runs whenever that answer is not provably
optimal). ``WbcResult.message`` says which: ``"active-set guess"`` or ``""``. proxsuite's own
answers are then polished by the same deterministic KKT solve, and its iterations are bounded
(``max_iter × (max_iter_in + 1)`` per tick): the same inputs give the same torques bit for bit,
and a tick's time is bounded even when the robot falls. :meth:`WholeBodyController.reset` (and
:meth:`~giwbc.control.balance.BalanceController.reset`) return to the freshly constructed state.

Per tick (G1 standing, 47 variables, 18 equalities, 63 inequalities; ``benchmarks/wbc_tick.py``
medians, one core): Pinocchio's ``computeAllTerms`` ~12 µs; the assembly ~21 µs — a handful of
numpy calls per task on one stacked Jacobian, the base orientation's constant Hessian ``w I`` on
the diagonal, both feet in one batch, the equation of motion's rows in one compiled kernel
(:mod:`giwbc.control.kernels`), views of the problem and of Pinocchio's ``Data`` prepared once;
the KKT guess ~24 µs (its ``dgesv`` ~16 µs, the system's assembly and check compiled:
:mod:`giwbc.control.qp.kernels`); ~60 µs in all.

Contacts can be added and removed at run time (their slots, ramps and force shares:
:mod:`giwbc.control.contact_set`): a contact's normal-force upper bound ramps over
``ramp_time`` (see :mod:`giwbc.control.contacts`); a removed contact keeps its slot with zero force
(no re-initialisation of the solver) — a 6D-wrench contact's motion rows then pin its wrench at
zero, so single-support ticks keep a regular KKT system — and a new contact name grows the
problem (one cold solve).

Output for a :class:`~giwbc.robot.interface.Robot`: joint torques ``tau``; and
``WbcResult.impedance``, an :class:`~giwbc.robot.interface.ImpedanceCommand` for actuators that
run their own PD loop: ``tau_ff = tau``, ``q_ref = q + v h + ½ q̈ h²``, ``v_ref = v + q̈ h`` (the
state the WBC predicts ``h = impedance_lookahead`` seconds ahead, default 0 — the measured state),
with *low* gains ``impedance_kp``/``impedance_kd``. At the measured state the actuator then
outputs exactly the WBC torque; between WBC ticks the gains only resist drift away from the
predicted motion, so they must stay well below a joint-PD controller's gains (they are a safety
net for latency, not the controller).
"""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from giwbc.control.contact_set import ContactSet, ContactSlot
from giwbc.control.contacts import Contact
from giwbc.control.kernels import dynamics_rows
from giwbc.control.kernels import warm as warm_kernels
from giwbc.control.kinodynamics import Kinodynamics
from giwbc.control.qp import QpProblem, QpSolution, QpSolver, QpStatus, make_solver
from giwbc.control.tasks import ContactForceRegularization, WbcTask, TaskStack
from giwbc.robot.interface import ImpedanceCommand

UNLIMITED = 1e10  # limits at or above this (Pinocchio uses DBL_MAX) count as "no limit"


class WbcStatus(enum.Enum):
    OK = "ok"
    QP_FAILED = "qp_failed"  # see WbcResult.qp_status; the result holds the fallback command
    INVALID_STATE = "invalid_state"  # q or v not finite; the result holds the fallback command


@dataclass(slots=True)
class WbcTimings:
    """Wall-clock seconds of one tick: Pinocchio pass, QP assembly, solver, and everything."""

    pinocchio: float = 0.0
    build: float = 0.0
    solve: float = 0.0
    total: float = 0.0


@dataclass(eq=False, slots=True)
class WbcResult:
    """One tick's output. ``tau`` is always finite (the fallback when ``status`` is not OK).

    ``qdd`` (nv) and ``forces`` (all contact variables) are NaN when the QP failed;
    ``iterations`` are the backend's (0 when the active-set guess answered);
    ``contact_wrenches`` maps each contact with non-zero activation to its 6D wrench
    ``(f, τ)`` about the contact origin *in the contact frame* (world axes:
    :meth:`WholeBodyController.contact_wrench_world`).
    """

    status: WbcStatus
    tau: np.ndarray
    qdd: np.ndarray
    forces: np.ndarray
    contact_wrenches: dict[str, np.ndarray]
    t: float
    qp_status: QpStatus | None = None
    iterations: int = 0
    message: str = ""
    failures: int = 0  # failed ticks so far (this one included)
    timings: WbcTimings = field(default_factory=WbcTimings)
    # inputs of the impedance command (joint coordinates)
    _q_joints: np.ndarray = field(default=None, repr=False)  # type: ignore[assignment]
    _v_joints: np.ndarray = field(default=None, repr=False)  # type: ignore[assignment]
    _gains: tuple = field(default=(), repr=False)

    @property
    def ok(self) -> bool:
        return self.status is WbcStatus.OK

    def failure(self) -> str | None:
        """Why this tick fell back to the safe command (status, QP status, message), or None when it solved."""
        if self.ok:
            return None
        return f"whole-body controller {self.status.value} ({self.qp_status.value if self.qp_status else 'no QP'}): {self.message}"

    @property
    def impedance(self) -> ImpedanceCommand:
        """The equivalent per-joint impedance command (see the module docstring); a new object
        at each access."""
        kp, kd, lookahead, fallback_kd = self._gains
        q, v = self._q_joints, self._v_joints
        if not self.ok:
            # Fallback: hold no position, damp, keep the fallback feed-forward.
            finite = np.all(np.isfinite(q)) and np.all(np.isfinite(v))
            q_ref = q.copy() if finite else np.zeros_like(self.tau)
            return ImpedanceCommand(q_ref, np.zeros_like(self.tau), np.zeros_like(self.tau), fallback_kd.copy(), self.tau.copy())
        qdd = self.qdd[len(self.qdd) - len(self.tau) :]
        h = lookahead
        return ImpedanceCommand(q + v * h + 0.5 * h * h * qdd, v + qdd * h, kp.copy(), kd.copy(), self.tau.copy())


def _as_joint_array(value: float | np.ndarray | None, n: int, what: str, default: float = 0.0) -> np.ndarray:
    array = np.broadcast_to(np.asarray(default if value is None else value, dtype=float), (n,)).copy()
    if not np.all(np.isfinite(array)) or np.any(array < 0):
        raise ValueError(f"{what} must be finite and >= 0 (one value or {n}), got {value}")
    return array


class WholeBodyController:
    """Inverse-dynamics QP controller over a Pinocchio model (see the module docstring).

    Parameters
    ----------
    model: the Pinocchio model (free-flyer root for a floating base; a fixed-base model works too).
    dt: control period, s (the internal clock when ``update`` gets no time; joint-limit horizon).
    solver: a backend name (``"proxsuite"``, ``"osqp"``, any qpsolvers name) or a :class:`QpSolver`.
    solver_settings: keyword settings for the named backend.
    n_base: unactuated leading velocity coordinates (default: 6 for a free flyer, else 0).
    torque_limits: per-joint |τ| bounds (default ``model.effortLimit``; ≥ 1e10 or inf: none).
    joint_limits: add acceleration bounds keeping joints inside position/velocity limits.
    joint_limit_horizon: time, s, over which the acceleration bounds must stop a joint at its limit.
    joint_limit_margin: rad, the position limits the bounds keep moved inward by this much (inside
    a deployment safety layer's soft limits, which stop the robot).
    acceleration_regularization: ``ε`` of ``ε ‖q̈‖²`` (strict convexity).
    impedance_kp, impedance_kd, impedance_lookahead: the impedance output (module docstring).
    fallback_decay: factor applied to the last good torques per failed tick.
    fallback_kd: damping of the fallback impedance command (default: ``impedance_kd``).
    relax_joint_limits: when the QP with the joint-limit bounds has no solution, solve it again
    without them (counted in ``relaxed_solves``) before falling back. A foot rolling on a rim or a
    point turns its ankle faster than the bounds' horizon allows, and their box then contradicts the
    contact rows (the model's foot is flat): the fallback's decaying torques let the ankle go at once.

    A :class:`ContactForceRegularization` (weight 1e-5, the weight shared by the contacts) is on
    from construction: with two or more contacts the forces are otherwise not unique (the QP's
    Hessian is singular in the internal forces) and proxsuite finds no KKT point on the G1 at any
    tick. :meth:`add_task` with another one replaces it; after :meth:`remove_task` of it, a failed
    tick's message says that it is missing.
    """

    def __init__(
        self,
        model: pin.Model,
        *,
        dt: float = 0.002,
        solver: str | QpSolver = "proxsuite",
        solver_settings: dict | None = None,
        n_base: int | None = None,
        torque_limits: np.ndarray | None = None,
        joint_limits: bool = False,
        joint_limit_horizon: float = 0.05,
        joint_limit_margin: float = 0.0,
        acceleration_regularization: float = 1e-6,
        impedance_kp: float | np.ndarray = 0.0,
        impedance_kd: float | np.ndarray = 0.0,
        impedance_lookahead: float = 0.0,
        fallback_decay: float = 0.9,
        fallback_kd: float | np.ndarray | None = None,
        relax_joint_limits: bool = False,
    ) -> None:
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be > 0, got {dt}")
        if not (0.0 <= fallback_decay <= 1.0):
            raise ValueError(f"fallback_decay must be in [0, 1], got {fallback_decay}")
        if not (acceleration_regularization >= 0 and math.isfinite(acceleration_regularization)):
            raise ValueError("acceleration_regularization must be finite and >= 0")
        if not (joint_limit_horizon > 0):
            raise ValueError("joint_limit_horizon must be > 0")
        if not (0.0 <= joint_limit_margin < 0.5):
            raise ValueError(f"joint_limit_margin must be in [0, 0.5) rad, got {joint_limit_margin}")
        self.kin = Kinodynamics(model, n_base=n_base)
        self.model = model
        self.dt = float(dt)
        kin = self.kin
        self.nv, self.n_base, self.n_joints = kin.nv, kin.n_base, kin.n_joints
        warm_kernels(kin.mass_matrix)  # (compiled once a process: not in a control loop's first ticks)
        self.solver = make_solver(solver, **(solver_settings or {})) if isinstance(solver, str) else solver
        nj = self.n_joints
        limits = model.effortLimit[self.n_base :] if torque_limits is None else np.asarray(torque_limits, dtype=float)
        if limits.shape != (nj,):
            raise ValueError(f"torque_limits must have {nj} entries, got shape {limits.shape}")
        if np.any(limits < 0) or np.any(np.isnan(limits)):
            raise ValueError("torque limits must be >= 0")
        self.torque_limits = np.where(np.isfinite(limits) & (limits < UNLIMITED), limits, np.inf)
        self.joint_limits = bool(joint_limits)
        self.joint_limit_horizon = float(joint_limit_horizon)
        lower = np.array(model.lowerPositionLimit[kin.joint_q], dtype=float)
        upper = np.array(model.upperPositionLimit[kin.joint_q], dtype=float)
        velocity = np.array(model.velocityLimit[self.n_base :], dtype=float)
        self.joint_limit_margin = float(joint_limit_margin)
        self._q_lower = np.where(np.abs(lower) < UNLIMITED, lower + self.joint_limit_margin, -np.inf)
        self._q_upper = np.where(np.abs(upper) < UNLIMITED, upper - self.joint_limit_margin, np.inf)
        self._v_limit = np.where(np.isfinite(velocity) & (velocity < UNLIMITED) & (velocity > 0), velocity, np.inf)
        self.acceleration_regularization = float(acceleration_regularization)
        self.impedance_kp = _as_joint_array(impedance_kp, nj, "impedance_kp")
        self.impedance_kd = _as_joint_array(impedance_kd, nj, "impedance_kd")
        self.impedance_lookahead = float(impedance_lookahead)
        self.fallback_decay = float(fallback_decay)
        self.fallback_kd = self.impedance_kd.copy() if fallback_kd is None else _as_joint_array(fallback_kd, nj, "fallback_kd")
        self.relax_joint_limits = bool(relax_joint_limits)  # (a caller may switch it)
        self.relaxed_solves = 0  # ticks solved without the joint-limit bounds (relax_joint_limits)
        # (zone rad, kp N m/rad, kd N m s/rad) of set_limit_spring; None: off (a caller may switch it per tick)
        self.limit_spring: tuple[float, float, float] | None = None

        self.tasks: list[WbcTask] = []
        self.force_regularization: ContactForceRegularization | None = ContactForceRegularization()
        self.contact_set = ContactSet(self.kin)
        self._stacks: dict[tuple, tuple[TaskStack, int]] = {}  # per task list (ids: its tasks are kept alive by the stack)
        self._bind_epoch = 0  # task binds so far (a stack last used before one is re-armed)
        self._stack: TaskStack | None = None
        self._structure = 0
        self._layout_dirty = True
        self._tasks_dirty = True
        self._time = 0.0
        self._last_tau: np.ndarray | None = None
        self.failures = 0
        self.consecutive_failures = 0
        self.ticks = 0
        self.problem: QpProblem | None = None

    # --- tasks -----------------------------------------------------------------------------------
    def add_task(self, task: WbcTask | ContactForceRegularization) -> WbcTask | ContactForceRegularization:
        """Add a task (or the contact-force regularisation); returns it. Names must be unique."""
        if isinstance(task, ContactForceRegularization):
            self.force_regularization = task
            self._layout_dirty = True
            return task
        if not isinstance(task, WbcTask):
            raise TypeError(f"expected a WbcTask, got {type(task).__name__}")
        if any(existing.name == task.name for existing in self.tasks):
            raise ValueError(f"a task named {task.name!r} already exists")
        if getattr(task, "bound_to", None) is not self.kin:  # (re-added, e.g. a swing foot's: bound already)
            task.bind(self.kin)
            self._bind_epoch += 1
        self.tasks.append(task)
        self._tasks_dirty = True
        return task

    def remove_task(self, name: str) -> None:
        if self.force_regularization is not None and self.force_regularization.name == name:
            self.force_regularization = None
            self._layout_dirty = True
            return
        for i, task in enumerate(self.tasks):
            if task.name == name:
                del self.tasks[i]
                self._tasks_dirty = True
                return
        raise KeyError(f"no task named {name!r}")

    def task(self, name: str) -> WbcTask:
        for task in self.tasks:
            if task.name == name:
                return task
        raise KeyError(f"no task named {name!r}; tasks: {[t.name for t in self.tasks]}")

    # --- contacts ----------------------------------------------------------------------------------
    def add_contact(self, contact: Contact, ramp_time: float = 0.0) -> Contact:
        """Make a contact (or re-make a removed one by name); its force bound ramps up over ``ramp_time`` s.

        A new name grows the problem (the solver re-initialises once); re-adding a known name
        with the same number of force variables reuses its slot.
        """
        if not isinstance(contact, Contact):
            raise TypeError(f"expected a Contact, got {type(contact).__name__}")
        if ramp_time < 0:
            raise ValueError("ramp_time must be >= 0")
        if self.contact_set.add(contact, ramp_time):
            self._layout_dirty = True
        return contact

    def remove_contact(self, name: str, ramp_time: float = 0.0) -> None:
        """Break a contact: its force bound ramps down to zero over ``ramp_time`` s, then its
        motion constraint is dropped (the slot stays, with zero force)."""
        if ramp_time < 0:
            raise ValueError("ramp_time must be >= 0")
        self.contact_set.remove(name, ramp_time)

    def forget_contact(self, name: str) -> None:
        """Delete a contact's slot altogether (shrinks the problem; the solver re-initialises)."""
        self.contact_set.forget(name)
        self._layout_dirty = True

    def contact(self, name: str) -> Contact:
        return self._slot(name).contact

    def contact_activation(self, name: str) -> float:
        """Current activation in [0, 1] (1: full force allowed; 0: broken)."""
        return self._slot(name).activation

    @property
    def contacts(self) -> list[Contact]:
        return [slot.contact for slot in self.contact_set.slots.values()]

    @property
    def active_contacts(self) -> list[str]:
        return [name for name, slot in self.contact_set.slots.items() if slot.engaged]

    def _slot(self, name: str) -> ContactSlot:
        return self.contact_set.slot(name)

    # --- layout ----------------------------------------------------------------------------------
    def _layout(self) -> None:
        """(Re)allocate every buffer for the current contacts and limits; write constant blocks.

        Row order is chosen so that the floating-base rows (last rows of ``A``) and the torque
        rows (first rows of ``C``) are adjacent in the shared ``[A; C]`` buffer: together they are
        the whole equation of motion ``[M, −JᵀΦ] x = Sᵀτ − h``, one (nv × n) block ``D`` filled by
        one copy of ``M`` and one copy of each contact's ``−JᵀΦ`` per tick.
        """
        nv, nb, nj = self.nv, self.n_base, self.n_joints
        contacts = self.contact_set
        n, eq = contacts.lay_out_columns(nv)
        n_eq = eq + nb
        limited = np.flatnonzero(np.isfinite(self.torque_limits))
        self._torque_all = len(limited) == nj
        self._torque_idx = limited
        n_torque = len(limited)
        ineq = contacts.lay_out_friction(n_torque)
        self.n_force = n - nv

        AC = np.zeros((n_eq + ineq, n))
        A, C = AC[:n_eq], AC[n_eq:]
        if self._torque_all:
            self._D = AC[eq : eq + nv]  # base rows of A, then the torque rows of C
        else:
            self._D = np.zeros((nv, n))
        self._base_b = slice(eq, n_eq)
        self._torque_rows = slice(0, n_torque)
        H = np.zeros((n, n))
        g = np.zeros(n)
        b = np.zeros(n_eq)
        limits = np.empty((2, ineq))  # l and u adjacent: backends copy both at once
        limits[0], limits[1] = -np.inf, np.inf
        lo, hi = limits
        lb = ub = None
        if self.joint_limits:
            lb = np.full(n, -np.inf)
            ub = np.full(n, np.inf)
            self._limit_bounds = np.zeros((4, nj))
            T = self.joint_limit_horizon
            s = 2.0 / (T * T)
            # rows: upper (position), upper (velocity), lower (position), lower (velocity) = c + dq q + dv v
            with np.errstate(invalid="ignore"):
                self._limit_c = np.array([self._q_upper * s, self._v_limit / T, self._q_lower * s, -self._v_limit / T])
            self._limit_dq = np.array([-s, 0.0, -s, 0.0])[:, None] * np.ones(nj)
            self._limit_dv = np.array([-s * T, -1.0 / T, -s * T, -1.0 / T])[:, None] * np.ones(nj)
        self._tau_lo = -self.torque_limits[limited]
        self._tau_hi = self.torque_limits[limited]
        contacts.write_constants(C)
        self._h_diag = np.lib.stride_tricks.as_strided(H, shape=(n,), strides=((n + 1) * H.itemsize,))
        self._H_qq, self._h_diag_q, self._g_q = H[:nv, :nv], self._h_diag[:nv], g[:nv]
        self._D_M = self._D[:, :nv]
        self._D_tau = self._D[nb:]
        self._tau_rows = slice(n_eq, n_eq + n_torque)  # the torque rows in [A; C] (all joints limited)
        self._b_base = b[eq:n_eq]
        self._l_torque, self._u_torque = lo[:n_torque], hi[:n_torque]
        self._neg_limits = -self.torque_limits
        self._tau = np.zeros(nj)

        # Structural patterns for sparse backends.
        h_pattern = np.zeros((n, n), dtype=bool)
        h_pattern[:nv, :nv] = True
        h_pattern[np.arange(n), np.arange(n)] = True
        ac_pattern = np.zeros_like(AC, dtype=bool)
        m_pattern, supports = self._tree_patterns()
        d_rows = np.concatenate([eq + np.arange(nb), n_eq + np.arange(n_torque)])  # rows of [A; C]
        d_source = np.concatenate([np.arange(nb), nb + limited])  # their rows of D
        ac_pattern[d_rows, :nv] = m_pattern[d_source]
        contacts.pattern(ac_pattern, supports, d_rows, d_source, n_eq)
        self._structure += 1
        self.problem = QpProblem(H, g, A, b, C, lo, hi, lb, ub, h_pattern, ac_pattern, self._structure)
        # (the force regularisation's diagonal is written when it changes only)
        contacts.bind(self.problem, self._D, self._h_diag[nv:], nv)
        self._layout_dirty = False
        self._tasks_dirty = True

    def _tree_patterns(self) -> tuple[np.ndarray, np.ndarray]:
        """Structural non-zeros of ``M`` (joints on one branch) and, per joint, the velocity
        columns a Jacobian of a frame on that joint can use (its supporting joints)."""
        model, nv = self.model, self.nv
        supports = np.zeros((model.njoints, nv), dtype=bool)
        for joint in range(1, model.njoints):
            for ancestor in model.supports[joint]:
                if ancestor > 0:
                    start = model.idx_vs[ancestor]
                    supports[joint, start : start + model.nvs[ancestor]] = True
        mass = np.zeros((nv, nv), dtype=bool)
        for joint in range(1, model.njoints):
            start = model.idx_vs[joint]
            cols = supports[joint]
            mass[start : start + model.nvs[joint]] |= cols
            mass[cols, start : start + model.nvs[joint]] = True
        return mass, supports

    def _layout_tasks(self) -> None:
        """The task stack of the current task list: a walker switches between a few task sets (a
        swing foot's pose task in or out), so each set's stack is kept and reused, with the same
        numbers as a new one: gains and references are re-gathered where their versions moved, and
        a task's constant rows (written only when ``rows_stale``, which only binding sets) are
        written again, with the constant Hessian part, when a task was bound since the stack's last
        use (a re-added task already bound to this controller is not bound again)."""
        key = (tuple(map(id, self.tasks)), self.acceleration_regularization)
        cached = self._stacks.get(key)
        if cached is None:
            stack = TaskStack(self.tasks, self.nv, self.acceleration_regularization)
            if len(self._stacks) >= 8:  # (a handful of task sets: bounded all the same)
                del self._stacks[next(iter(self._stacks))]
        else:
            stack, epoch = cached
            if epoch != self._bind_epoch:  # a task was bound since: its rows may have changed
                for task in stack.tasks:
                    task.rows_stale = True
                stack._hessian_stale = True
        self._stacks[key] = (stack, self._bind_epoch)
        self._stack = stack
        self._tasks_dirty = False

    # --- the tick ----------------------------------------------------------------------------------
    def build(self, q: np.ndarray, v: np.ndarray, t: float | None = None) -> QpProblem:
        """Update the kinematics and dynamics for ``(q, v)`` and assemble the QP.

        The returned problem's arrays are the controller's buffers, overwritten at the next tick
        (``problem.copy()`` to keep one). ``ValueError`` for wrong shapes or a non-finite state.
        """
        q, v = self.kin.check_state(q, v)
        if not Kinodynamics.is_finite(q, v):
            raise ValueError("state (q, v) is not finite")
        self.kin.update(q, v)
        self._assemble(self._tick_time(t))
        assert self.problem is not None
        return self.problem

    def _tick_time(self, t: float | None) -> float:
        if t is None:
            t = self._time + (self.dt if self.ticks else 0.0)
        self._time = float(t)
        return self._time

    def _assemble(self, t: float) -> None:
        if self._layout_dirty:
            self._layout()
        if self._tasks_dirty:
            self._layout_tasks()
        kin = self.kin
        p = self.problem
        nb = self.n_base
        h = kin.nonlinear_effects

        # Tasks: H_qq = Σ Jᵀ W J + ε I, g_q = −Σ Jᵀ W (ẍ* − J̇ v).
        stack = self._stack
        stack.evaluate(kin)
        stack.hessian(self._H_qq, self._h_diag_q)
        stack.gradient(self._g_q)

        # Equation of motion block D = [M, −JᵀΦ]: base rows (equalities), torque rows; every
        # joint limited (the G1): M, −h_b and the torque rows' limits in one compiled call.
        if self._torque_all:
            dynamics_rows(self._D_M, kin.mass_matrix, h, self._b_base, self._tau_lo, self._tau_hi, self._l_torque, self._u_torque)
        else:
            self._D_M[...] = kin.mass_matrix
            if nb:
                np.negative(h[:nb], out=self._b_base)

        # Contacts: ramps, motion rows, −JᵀΦ columns; the force regularisation when it changed.
        self.contact_set.assemble(t, self.force_regularization)

        # Torque limits: τ_min − h_j ≤ M_j q̈ − (JᵀΦ)_j f ≤ τ_max − h_j (all limited: written above).
        if not self._torque_all:
            hj = h[nb:]
            p.A[self._base_b] = self._D[:nb]
            if len(self._torque_idx):
                idx = self._torque_idx
                rows = self._torque_rows
                p.C[rows] = self._D[nb:][idx]
                p.l[rows] = self._tau_lo - hj[idx]
                p.u[rows] = self._tau_hi - hj[idx]

        if self.joint_limits:
            self._joint_limit_bounds(p)

    def _solve_without_limits(self) -> QpSolution:
        """The last built problem solved again with its joint-limit bounds open (the next build
        writes them anew); the relaxed solve counted."""
        p = self.problem
        assert p is not None and p.lb is not None and p.ub is not None
        p.lb.fill(-np.inf)
        p.ub.fill(np.inf)
        solution = self.solver.solve(p)
        if solution.ok:
            self.relaxed_solves += 1
        return solution

    def _joint_limit_bounds(self, p: QpProblem) -> None:
        """q̈ bounds that stop each joint at its position limit within the horizon ``T``
        (``q + v T + ½ q̈ T² ≤ q_max``) and keep its velocity inside its limit (``|v + q̈ T| ≤ v_max``);
        where they conflict (state already outside), the upper bound wins so the box stays non-empty."""
        kin = self.kin
        bounds = self._limit_bounds
        np.multiply(self._limit_dq, kin.q[kin.joint_q], out=bounds)
        bounds += self._limit_c
        bounds += self._limit_dv * kin.v[kin.joint_v]
        upper = p.ub[self.n_base : self.nv]  # type: ignore[index]
        lower = p.lb[self.n_base : self.nv]  # type: ignore[index]
        np.minimum(bounds[0], bounds[1], out=upper)
        np.maximum(bounds[2], bounds[3], out=lower)
        np.minimum(lower, upper, out=lower)

    def reset(self) -> None:
        """Forget every trace of past ticks — afterwards the controller behaves exactly like a
        freshly constructed one with the same tasks and contacts: the clock and tick count, the
        last torque (the fallback's), the failure counters, the contacts (each made again as by
        its last :meth:`add_contact`: activation 0, its ramp restarted, its reference pose taken
        at the next tick), the solver's warm start and active set, and every problem buffer
        (re-laid out at the next tick). Tasks, their references, gains and weights are
        configuration: kept (:meth:`BalanceController.reset` re-anchors its references)."""
        self._time = 0.0
        self.ticks = 0
        self._last_tau = None
        self.failures = 0
        self.relaxed_solves = 0
        self.consecutive_failures = 0
        self.contact_set.reset()
        self._layout_dirty = True
        self._tasks_dirty = True
        self._stacks.clear()
        self._stack = None
        self.problem = None
        self.solver.reset()

    def solve(self, problem: QpProblem | None = None) -> QpSolution:
        """Solve the problem of the last :meth:`build` (or a given one) with the backend."""
        problem = self.problem if problem is None else problem
        if problem is None:
            raise RuntimeError("call build(q, v, t) before solve()")
        return self.solver.solve(problem)

    def update(self, q: np.ndarray, v: np.ndarray, t: float | None = None) -> WbcResult:
        """One control tick: build, solve, recover the torques. Never raises on a numerical
        failure or a non-finite state (wrong *shapes* raise ``ValueError``)."""
        clock = time.perf_counter
        start = clock()
        kin = self.kin
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if q.shape != kin.q_shape or v.shape != kin.v_shape:
            kin.check_state(q, v)  # raises, naming the wrong shape
        self.ticks += 1
        if not math.isfinite(q.dot(q) + v.dot(v)):  # (ndarray.dot: numpy's dot without np.dot's dispatch, ~0.3 µs a call)
            return self._fallback(q, v, self._tick_time(t), WbcStatus.INVALID_STATE, None, "state (q, v) is not finite", start, valid_state=False)
        kin.update(q, v, checked=True)
        t_pin = clock()
        if t is None:
            t = self._time + self.dt  # (as _tick_time: the tick count is already >= 1 here)
        self._time = t = float(t)
        self._assemble(t)
        t_build = clock()
        solution = self.solver.solve(self.problem)  # type: ignore[arg-type]
        if not solution.ok and self.joint_limits and self.relax_joint_limits:
            solution = self._solve_without_limits()
        t_solve = clock()
        if not solution.ok:
            return self._fallback(q, v, t, WbcStatus.QP_FAILED, solution, self._failure_message(solution), start, timings=(t_pin, t_build, t_solve))
        x = solution.x
        nv = self.nv
        rows = solution.rows
        if rows is not None and self._torque_all:
            tau = np.add(rows[self._tau_rows], kin.nonlinear_effects[self.n_base :])  # (JᵀΦ … ) x is there already
        else:
            tau = self._D_tau.dot(x)
            tau += kin.nonlinear_effects[self.n_base :]
        if self.limit_spring is not None:
            tau += self._limit_spring_torque(q, v)
        np.minimum(tau, self.torque_limits, out=tau)
        np.maximum(tau, self._neg_limits, out=tau)
        wrenches = self.contact_set.wrenches(x)
        self._last_tau = tau
        self.consecutive_failures = 0
        end = clock()
        return WbcResult(
            WbcStatus.OK, tau, x[:nv], x[nv:], wrenches, t, solution.status, solution.iterations, solution.message, self.failures,
            WbcTimings(t_pin - start, t_build - t_pin, t_solve - t_build, end - start),
            q[kin.joint_q].copy(), v[kin.joint_v].copy(), self._gains,
        )

    def set_limit_spring(self, zone: float, kp: float, kd: float) -> None:
        """A joint within ``zone`` rad of its kept position limit (the limit moved in by
        ``joint_limit_margin``) gets ``−kp (q − q_zone) − kd q̇`` N m on top of the QP's torque,
        ``q_zone`` the zone's inner edge, the damping only while it moves further in (mirrored
        at a lower limit); elsewhere nothing (the torque is the QP's, bit for bit).

        Why not the QP's acceleration bounds (``joint_limits``): they act through the model, in
        which a stance foot is flat on the floor, so holding an ankle off its limit means moving
        the whole body. A real foot that rolls on its rim (a rounded or pointed sole) turns with
        its ankle roll joint, and only a torque at that joint turns it back: this spring is that
        torque, a soft stop before the hard one (which the plant applies and the model ignores)."""
        if not (math.isfinite(zone) and zone > 0.0 and math.isfinite(kp) and kp >= 0.0 and math.isfinite(kd) and kd >= 0.0):
            raise ValueError(f"limit spring: need zone > 0 rad and finite kp, kd >= 0, got {zone}, {kp}, {kd}")
        self.limit_spring = (float(zone), float(kp), float(kd))

    def _limit_spring_torque(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The spring's joint torques (n_joints,) at state ``(q, v)``: zero outside the zones."""
        zone, kp, kd = self.limit_spring  # type: ignore[misc]
        kin = self.kin
        qj, vj = q[kin.joint_q], v[kin.joint_v]
        upper = qj - (self._q_upper - zone)  # > 0 inside the upper zone
        lower = (self._q_lower + zone) - qj  # > 0 inside the lower zone
        tau = np.zeros(self.n_joints)
        inside_up = upper > 0.0
        inside_low = lower > 0.0
        tau[inside_up] = -kp * upper[inside_up] - kd * np.maximum(vj[inside_up], 0.0)
        tau[inside_low] = kp * lower[inside_low] - kd * np.minimum(vj[inside_low], 0.0)
        return tau

    def _failure_message(self, solution: QpSolution) -> str:
        """The backend's message; with contact forces but no (or a zero-weight) force
        regularisation, also the likely cause: forces that are not unique."""
        reg = self.force_regularization
        if self.problem is not None and self.problem.n > self.nv and (reg is None or reg.weight == 0.0):
            return (f"{solution.message} (no contact-force regularisation: with several contacts the forces are not unique;"
                    " add a ContactForceRegularization)")
        return solution.message

    def _fallback(
        self,
        q: np.ndarray,
        v: np.ndarray,
        t: float,
        status: WbcStatus,
        solution: QpSolution | None,
        message: str,
        start: float,
        *,
        valid_state: bool = True,
        timings: tuple[float, float, float] | None = None,
    ) -> WbcResult:
        """A safe command when no QP solution is available: the last good torques decayed by
        ``fallback_decay`` per failed tick; before any success, zero torque on a floating base and
        gravity compensation ``g(q)`` on a fixed base. The impedance output becomes pure damping."""
        self.failures += 1
        self.consecutive_failures += 1
        nj = self.n_joints
        if self._last_tau is not None:
            tau = self._last_tau * self.fallback_decay
        elif valid_state and self.n_base == 0:
            tau = np.clip(np.array(self.kin.generalized_gravity), -self.torque_limits, self.torque_limits)
        else:
            tau = np.zeros(nj)
        self._last_tau = tau
        end = time.perf_counter()
        if timings is None:
            timing = WbcTimings(total=end - start)
        else:
            t_pin, t_build, t_solve = timings
            timing = WbcTimings(t_pin - start, t_build - t_pin, t_solve - t_build, end - start)
        n = self.problem.n if self.problem is not None else self.nv
        kin = self.kin
        return WbcResult(
            status, tau, np.full(self.nv, np.nan), np.full(n - self.nv, np.nan), {}, t,
            None if solution is None else solution.status, 0 if solution is None else solution.iterations,
            message, self.failures, timing,
            np.array(q[kin.joint_q]), np.array(v[kin.joint_v]), self._gains,
        )

    @property
    def _gains(self) -> tuple:
        return (self.impedance_kp, self.impedance_kd, self.impedance_lookahead, self.fallback_kd)

    # --- inspection ------------------------------------------------------------------------------
    def contact_wrench_world(self, name: str, result: WbcResult) -> np.ndarray:
        """A contact's wrench of ``result`` with world axes, about the contact origin (force, torque).
        Uses the current kinematics: call before the next update."""
        slot = self._slot(name)
        if name not in result.contact_wrenches:
            return np.zeros(6)
        rotation = slot.contact.placement_in_world(self.kin).rotation
        wrench = result.contact_wrenches[name]
        return np.concatenate([rotation @ wrench[:3], rotation @ wrench[3:]])

    def contact_forces(self, name: str, result: WbcResult) -> np.ndarray:
        """A contact's force variables in ``result`` (contact frame; 6D wrench or 4 × 3 corners)."""
        columns = self.contact_columns(name)
        return result.forces[columns.start - self.nv : columns.stop - self.nv]

    def contact_columns(self, name: str) -> slice:
        """The slice of a contact's force variables in ``x``."""
        if self._layout_dirty:
            self._layout()
        return self._slot(name).columns

    def generalized_contact_forces(self, forces: np.ndarray) -> np.ndarray:
        """``Σ Jᵀ Φ f`` (nv,) for the current kinematics and a vector of force variables."""
        out = np.zeros(self.nv)
        for slot in self.contact_set.slots.values():
            if slot.engaged:
                c = slot.contact
                f = forces[slot.columns.start - self.nv : slot.columns.stop - self.nv]
                out += c.jacobian.T @ c.wrench_in_contact_frame(f)
        return out
