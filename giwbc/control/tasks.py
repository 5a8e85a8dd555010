"""Weighted tasks of the whole-body QP, each a small class (pink / mink style).

An acceleration task has a Jacobian ``J`` (dim × nv), a drift ``J̇ v``, a position error ``e``
(reference minus measured), a velocity reference ``v_ref`` (so ``ė = v_ref − J v``), gains
``Kp``, ``Kd`` and a feed-forward ``ẍ_ref``. It asks for

    J q̈ + J̇ v = ẍ*,   ẍ* = ẍ_ref + Kp e + Kd ė,

and enters the cost as ``‖J q̈ − (ẍ* − J̇ v)‖²_W`` with ``W = diag(weight)``.

A task only *measures*: :meth:`WbcTask.write` puts ``J``, ``e`` and ``J̇ v`` into rows of buffers the
controller owns; by default from the pure :meth:`WbcTask.compute_error`, :meth:`WbcTask.compute_jacobian`
and :meth:`WbcTask.compute_drift`, which is all a new task needs to define. The base-class side
of the contract — gains, weights, references, and turning
all tasks into one least-squares term — is evaluated by the controller for all tasks at once
(:class:`TaskStack`: a handful of numpy calls per tick, whatever the number of tasks).
:meth:`WbcTask.compute` fills ``jacobian``, ``drift``, ``error`` and ``error_velocity`` for inspection
and for the finite-difference tests.

A :class:`ContactForceRegularization` acts on the contact-force variables instead:
``‖f − f_ref‖²_W``.

Weights and gains are scalars or per-row arrays; references, gains and weights can change at any
time (each change bumps the task's ``version``, which the controller watches).
"""

from __future__ import annotations

import abc
import math

import numpy as np
import pinocchio as pin

from giwbc.control.kinodynamics import LWA, Kinodynamics

_log3 = pin.log3
_frame_jacobian = pin.getFrameJacobian
_update_placement = pin.updateFramePlacement
_classical_acceleration = pin.getFrameClassicalAcceleration


def _row_vector(value: float | np.ndarray, dim: int, what: str) -> np.ndarray:
    array = np.broadcast_to(np.asarray(value, dtype=float), (dim,)).copy()
    if not np.all(np.isfinite(array)) or np.any(array < 0):
        raise ValueError(f"{what} must be finite and >= 0, got {value}")
    return array


def _vector(value: np.ndarray | list[float], dim: int, what: str) -> np.ndarray:
    """A finite float copy of ``value`` with ``dim`` entries (cheap: references change every tick)."""
    array = np.array(value, dtype=float)
    if array.shape != (dim,):
        array = array.reshape(-1)
        if array.shape != (dim,):
            raise ValueError(f"{what} must have {dim} entries, got shape {np.shape(value)}")
    if not math.isfinite(sum(array.tolist())):  # (not finite iff an entry is not, or the sum overflows; a third of a dot's cost)
        raise ValueError(f"{what} must be finite, got {array}")
    return array


def critical_damping(kp: float | np.ndarray) -> np.ndarray | float:
    """``Kd = 2 √Kp``: the damping gain of a critically damped double integrator."""
    return 2.0 * np.sqrt(kp)


class WbcTask(abc.ABC):
    """Base class of the whole-body controller's acceleration tasks (see the module docstring).

    Named apart from the RL :class:`giwbc.tasks.Task`. A task author writes two pure functions of
    the kinodynamics, :meth:`compute_error` (reference minus measured) and
    :meth:`compute_jacobian`, plus :meth:`compute_drift` (``J̇ v``) when it is not zero; the
    default :meth:`write` copies them into the controller's rows. Hot tasks override
    :meth:`write` to write in place instead; a task whose Jacobian is constant
    (``constant_jacobian``) writes its rows only when ``rows_stale`` is set, and one whose drift is
    zero (``zero_drift``) never writes it.
    """

    constant_jacobian = False
    zero_drift = False
    constant_gram = False  # JᵀWJ constant although J is not (see TaskStack)

    def constant_gram_matrix(self, nv: int) -> np.ndarray:
        """``JᵀWJ`` (nv, nv) of a ``constant_gram`` task."""
        raise NotImplementedError

    def __init__(
        self,
        name: str,
        dim: int,
        *,
        weight: float | np.ndarray = 1.0,
        kp: float | np.ndarray = 0.0,
        kd: float | np.ndarray | None = None,
    ) -> None:
        self.name = name
        self.dim = int(dim)
        self.version = 0  # bumped by weight and gain changes
        self.ref_version = 0  # bumped by velocity / acceleration reference changes
        self.rows_stale = True
        self._zeros = np.zeros(self.dim)
        self._zeros.flags.writeable = False  # shared default reference
        self.acceleration_ref = self._zeros
        self.velocity_ref = self._zeros
        self.set_weight(weight)
        self.set_gains(kp, kd)
        self.jacobian = np.zeros((self.dim, 0))
        self.drift = np.zeros(self.dim)
        self.error = np.zeros(self.dim)
        self.error_velocity = np.zeros(self.dim)
        self.nv = 0
        self.bound_to: Kinodynamics | None = None  # the last :meth:`bind`'s (a controller re-adding the task skips it)

    # --- settings ------------------------------------------------------------------------------
    def _changed(self) -> None:
        self.version += 1

    def set_weight(self, weight: float | np.ndarray) -> None:
        """Cost weight, a scalar or one per row (>= 0)."""
        self.weight = _row_vector(weight, self.dim, f"task {self.name!r} weight")
        self._changed()

    def set_gains(self, kp: float | np.ndarray, kd: float | np.ndarray | None = None) -> None:
        """Proportional and derivative gains; ``kd=None`` is critical damping ``2 √kp``."""
        self.kp = _row_vector(kp, self.dim, f"task {self.name!r} kp")
        self.kd = _row_vector(critical_damping(self.kp) if kd is None else kd, self.dim, f"task {self.name!r} kd")
        self._changed()

    def _set_rates(self, velocity: np.ndarray | None, acceleration: np.ndarray | None, checked: bool = False) -> None:
        """``checked``: both are already finite float arrays of ``dim`` entries that this task may keep."""
        if velocity is None and acceleration is None and self.velocity_ref is self._zeros and self.acceleration_ref is self._zeros:
            return  # no rates before, none now: nothing for the controller to gather again
        if checked:
            self.velocity_ref = self._zeros if velocity is None else velocity
            self.acceleration_ref = self._zeros if acceleration is None else acceleration
        else:
            self.velocity_ref = self._zeros if velocity is None else _vector(velocity, self.dim, "velocity reference")
            self.acceleration_ref = self._zeros if acceleration is None else _vector(acceleration, self.dim, "acceleration reference")
        self.ref_version += 1

    # --- evaluation ----------------------------------------------------------------------------
    def bind(self, kin: Kinodynamics) -> None:
        """Resolve names in the model (called when the task is first added to a controller;
        it depends on the model only, so a controller re-adding the task skips it)."""
        self.nv = kin.nv
        self.rows_stale = True
        self.bound_to = kin

    def compute_error(self, kin: Kinodynamics) -> np.ndarray:
        """``e`` (dim,): reference minus measured, at the state of ``kin``."""
        raise NotImplementedError(f"{type(self).__name__} implements neither compute_error nor write")

    def compute_jacobian(self, kin: Kinodynamics) -> np.ndarray:
        """``J`` (dim, nv): the task's rows of the generalized velocity, at the state of ``kin``."""
        raise NotImplementedError(f"{type(self).__name__} implements neither compute_jacobian nor write")

    def compute_drift(self, kin: Kinodynamics) -> np.ndarray:
        """``J̇ v`` (dim,); zero unless overridden."""
        return self._zeros

    def write(self, kin: Kinodynamics, rows: np.ndarray, error: np.ndarray, drift: np.ndarray) -> None:
        """Hot path: write ``J`` into ``rows`` (dim, nv), ``e`` into ``error`` and ``J̇ v`` into ``drift``.

        By default from :meth:`compute_jacobian`, :meth:`compute_error` and :meth:`compute_drift`.
        """
        rows[...] = self.compute_jacobian(kin)
        error[...] = self.compute_error(kin)
        drift[...] = self.compute_drift(kin)

    def compute(self, kin: Kinodynamics) -> None:
        """Fill ``jacobian``, ``drift``, ``error`` and ``error_velocity`` for the current state."""
        rows = np.zeros((self.dim, kin.nv))
        error = np.zeros(self.dim)
        drift = np.zeros(self.dim)
        stale, self.rows_stale = self.rows_stale, True
        self.write(kin, rows, error, drift)
        self.rows_stale = stale
        self.jacobian, self.error, self.drift = rows, error, drift
        self.error_velocity = self.velocity_ref - rows @ kin.v

    def desired_acceleration(self) -> np.ndarray:
        """``ẍ* = ẍ_ref + Kp e + Kd ė`` (after :meth:`compute`)."""
        return self.acceleration_ref + self.kp * self.error + self.kd * self.error_velocity

    def residual(self, qdd: np.ndarray) -> np.ndarray:
        """``J q̈ + J̇ v − ẍ*`` (after :meth:`compute`): how far an acceleration is from the wish."""
        return self.jacobian @ qdd + self.drift - self.desired_acceleration()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, dim={self.dim})"


class TaskStack:
    """All tasks of a controller as one weighted least-squares term ``‖J_w q̈ − b_w‖²``.

    Row blocks of shared buffers hold each task's ``J``, ``e`` and ``J̇ v`` and its references;
    per tick::

        J_w = √W J,   b_w = √W Kp e − Kd (J_w v) − √W J̇ v + √W ẍ_ref + √W Kd v_ref

    (``√W Kd J v = Kd J_w v``): the five signals are the rows of one (5, m) array and
    ``−b_w = Σ_rows(K ⊙ signals)`` (gains stored negated) is two numpy calls for all tasks, the
    gradient ``−J_wᵀ b_w`` one more. References are copied in only when a task's ``ref_version``
    changes, gains and weights gathered only when its ``version`` does.

    Rows come in three groups: tasks whose Gram matrix ``JᵀWJ`` changes with the state (CoM,
    momentum, frame positions) — the only rows of the per-tick Hessian product —; tasks whose
    rows change but whose Gram matrix does not (``constant_gram``: the orientation of the
    floating base, ``J = [0, R, 0]`` so ``JᵀWJ = w I``); tasks with a constant Jacobian (posture).
    The last two contribute ``hessian_constant`` (with ``ε I``), added on the diagonal only when
    it is diagonal (it is for the balance controller).
    """

    def __init__(self, tasks: list[WbcTask], nv: int, regularization: float = 0.0) -> None:
        self.groups = [self._group(task) for task in tasks]
        order = sorted(range(len(tasks)), key=lambda i: self.groups[i])  # stable
        self.tasks = [tasks[i] for i in order]
        self.groups = [self.groups[i] for i in order]
        dims = [task.dim for task in self.tasks]
        m = sum(dims)
        self.m, self.nv = m, nv
        self.m_varying = mv = sum(d for d, grp in zip(dims, self.groups) if grp == 0)
        self.m_rows = mr = sum(d for d, grp in zip(dims, self.groups) if grp < 2)  # rows written every tick
        self.regularization = float(regularization)
        self.J = np.zeros((m, nv))  # raw Jacobians
        self.Jw = np.zeros((m, nv))  # weighted
        self.signals = np.zeros((5, m))  # rows: e, J_w v, J̇ v, ẍ_ref, v_ref
        self.error, self._jv, self.drift, self._acc_ref, self._vel_ref = self.signals
        self._nb = np.zeros(m)  # −b_w
        self.hessian_constant = regularization * np.eye(nv)
        self._gains = np.zeros((5, m))  # rows, negated: −√W Kp, Kd, √W, −√W, −√W Kd
        self._products = np.zeros((5, m))
        self._sw_col = np.zeros((m, 1))
        self._J_rows, self._Jw_rows, self._sw_rows = self.J[:mr], self.Jw[:mr], self._sw_col[:mr]
        self._Jw_varying = self.Jw[:mv]
        self._Jw_varying_T = self._Jw_varying.T
        self.views = []
        start = 0
        for task in self.tasks:
            rows = slice(start, start + task.dim)
            self.views.append((task, self.J[rows], self.error[rows], self.drift[rows], rows))
            task.rows_stale = True
            start += task.dim
        self._writes = [(task.write, rows, error, drift) for task, rows, error, drift, _ in self.views]
        self._rate_rows = [(self._acc_ref[rows], self._vel_ref[rows]) for *_, rows in self.views]
        self._constant_tasks = [task for task, group in zip(self.tasks, self.groups) if group == 2]
        self._versions = [-1] * len(self.tasks)
        self._ref_versions = [-1] * len(self.tasks)
        self._hessian_stale = True
        self._regrouped = False
        self._constant_diagonal: np.ndarray | None = None
        self._matmul, self._multiply = np.matmul, np.multiply
        self._ones = np.ones(5)

    @staticmethod
    def _group(task: WbcTask) -> int:
        if task.constant_jacobian:
            return 2
        return 1 if task.constant_gram else 0

    @property
    def b(self) -> np.ndarray:
        """``b_w`` (m,) of the last :meth:`evaluate`."""
        return -self._nb

    def _refresh(self) -> None:
        for i, (task, _, _, _, rows) in enumerate(self.views):
            if self._versions[i] != task.version:
                if self._group(task) != self.groups[i]:
                    # A task changed kind (non-uniform weights on the base orientation): regroup.
                    self.__init__(self.tasks, self.nv, self.regularization)  # type: ignore[misc]
                    self._regrouped = True
                    return
                sw = np.sqrt(task.weight)
                self._sw_col[rows, 0] = sw
                gains = self._gains
                gains[0, rows] = -sw * task.kp
                gains[1, rows] = task.kd
                gains[2, rows] = sw
                gains[3, rows] = -sw
                gains[4, rows] = -sw * task.kd
                self._hessian_stale = self._hessian_stale or self.groups[i] > 0
                self._versions[i] = task.version
            if self._ref_versions[i] != task.ref_version:
                self._acc_ref[rows] = task.acceleration_ref
                self._vel_ref[rows] = task.velocity_ref
                self._ref_versions[i] = task.ref_version
        if self._hessian_stale:
            mr = self.m_rows
            constant = self.Jw[mr:] = self.J[mr:] * self._sw_col[mr:]
            hessian = constant.T @ constant + self.regularization * np.eye(self.nv)
            for task, group in zip(self.tasks, self.groups):
                if group == 1:
                    hessian += task.constant_gram_matrix(self.nv)
            self.hessian_constant = hessian
            diagonal = np.diag(hessian)
            # A diagonal constant part (selection tasks, ε I, base orientation) is added on the diagonal only.
            self._constant_diagonal = diagonal.copy() if np.count_nonzero(hessian - np.diag(diagonal)) == 0 else None
            self._hessian_stale = False

    def evaluate(self, kin: Kinodynamics) -> None:
        """Write every task and form ``Jw`` and ``−b_w`` for the current state."""
        for task in self._constant_tasks:
            if task.rows_stale:
                self._hessian_stale = True
        for write, rows, error, drift in self._writes:
            write(kin, rows, error, drift)
        tasks, versions, ref_versions = self.tasks, self._versions, self._ref_versions
        for i in range(len(tasks)):
            task = tasks[i]
            if task.version != versions[i]:
                self._refresh()
                break
            if task.ref_version != ref_versions[i]:  # (a swing foot's, every tick: its rates only)
                acceleration, velocity = self._rate_rows[i]
                acceleration[...] = task.acceleration_ref  # (a slice write: np.copyto without its dispatch)
                velocity[...] = task.velocity_ref
                ref_versions[i] = task.ref_version
        if self._hessian_stale:
            self._refresh()
        if self._regrouped:  # new buffers: write every task again
            self._regrouped = False
            return self.evaluate(kin)
        self._multiply(self._J_rows, self._sw_rows, out=self._Jw_rows)
        self._matmul(self.Jw, kin.v, out=self._jv)
        self._multiply(self._gains, self.signals, out=self._products)
        self._ones.dot(self._products, out=self._nb)  # the column sums (faster than add.reduce)

    def hessian(self, out: np.ndarray, diagonal: np.ndarray | None = None) -> None:
        """``out = Σ Jᵀ W J + ε I`` (nv, nv), after :meth:`evaluate`; ``diagonal``, a writable
        view of ``out``'s diagonal, lets a diagonal constant part be added there only."""
        self._matmul(self._Jw_varying_T, self._Jw_varying, out=out)
        if diagonal is not None and self._constant_diagonal is not None:
            diagonal += self._constant_diagonal
        else:
            out += self.hessian_constant

    def gradient(self, out: np.ndarray) -> None:
        """``out = −Σ Jᵀ W (ẍ* − J̇ v)`` (nv,), after :meth:`evaluate`."""
        self._matmul(self._nb, self.Jw, out=out)


class ComTask(WbcTask):
    """Centre-of-mass position (world frame, 3 rows)."""

    def __init__(self, name: str = "com", *, weight: float | np.ndarray = 1.0, kp: float | np.ndarray = 100.0, kd=None) -> None:
        super().__init__(name, 3, weight=weight, kp=kp, kd=kd)
        self.position_ref: np.ndarray | None = None  # None: hold the CoM where it is at the first tick

    def set_reference(self, position: np.ndarray, velocity: np.ndarray | None = None, acceleration: np.ndarray | None = None) -> None:
        self.position_ref = _vector(position, 3, "CoM position reference")
        self._set_rates(velocity, acceleration)

    def write(self, kin: Kinodynamics, rows: np.ndarray, error: np.ndarray, drift: np.ndarray) -> None:
        com = kin.com
        if self.position_ref is None:
            self.position_ref = np.array(com)
        rows[...] = kin.com_jacobian
        np.subtract(self.position_ref, com, out=error)
        kin.com_drift_into(drift)


class FramePoseTask(WbcTask):
    """Pose of a model frame: ``[position; orientation]`` rows in world axes, a subset selectable.

    Position error ``p_ref − p``; orientation error ``log3(R_ref Rᵀ)`` (world axes) — the rotation
    vector taking the frame to its reference. Velocities are the frame's ``LOCAL_WORLD_ALIGNED``
    twist ``J v`` (origin velocity, angular velocity). ``mask`` picks rows of
    ``(x, y, z, rx, ry, rz)``.
    """

    def __init__(
        self,
        frame: str,
        name: str | None = None,
        *,
        mask: np.ndarray | list[bool] | None = None,
        weight: float | np.ndarray = 1.0,
        kp: float | np.ndarray = 100.0,
        kd=None,
    ) -> None:
        selection = np.ones(6, dtype=bool) if mask is None else np.asarray(mask, dtype=bool).reshape(6)
        if not selection.any():
            raise ValueError("a frame task needs at least one selected row")
        self.frame = frame
        self.rows = np.flatnonzero(selection)
        contiguous = bool(np.all(np.diff(self.rows) == 1))
        self._select = slice(int(self.rows[0]), int(self.rows[-1]) + 1) if contiguous else self.rows
        self._linear = bool(self.rows[0] < 3)
        self._angular = bool(self.rows[-1] >= 3)
        self._full = len(self.rows) == 6
        super().__init__(name or f"{frame}_pose", len(self.rows), weight=weight, kp=kp, kd=kd)
        self.frame_id = -1
        self.reference: pin.SE3 | None = None  # None: hold the pose at the first tick
        self._error6 = np.zeros(6)
        self._root = False
        self._angular_rows = slice(0, 3) if len(self.rows) == 3 and self._angular and not self._linear else self.rows[self.rows >= 3] - 3
        self._all_angular = isinstance(self._angular_rows, slice)
        self._relative = np.zeros((3, 3))
        self._placement_views: tuple | None = None  # (Data, rotation, translation) of data.oMf[frame]
        self._error_halves: tuple = (None,)  # (error rows, their position and rotation halves, Rᵀ view)

    def bind(self, kin: Kinodynamics) -> None:
        super().bind(kin)
        self.frame_id = kin.frame_id(self.frame)
        frame = kin.model.frames[self.frame_id]
        # Orientation of a frame on the floating base itself: its LWA angular rows are
        # [0, R_base, 0] (the free-flyer's angular velocity is in the base frame) and its drift
        # is zero, so they are written from the base rotation with no Pinocchio call.
        self._root = kin.free_flyer and kin.n_base == 6 and int(frame.parentJoint) == 1 and not self._linear
        rotation = np.array(frame.placement.rotation)
        self._frame_rotation = None if np.array_equal(rotation, np.eye(3)) else rotation
        if not self._linear:  # rows of the angular block
            self._angular_rows = slice(0, 3) if len(self.rows) == 3 else self.rows - 3
            self._all_angular = len(self.rows) == 3

    @property
    def constant_gram(self) -> bool:  # type: ignore[override]
        """The base-orientation task with all three rows and one weight: ``JᵀWJ = w I``."""
        return bool(getattr(self, "_root", False) and len(self.rows) == 3 and np.all(self.weight == self.weight[0]))

    def constant_gram_matrix(self, nv: int) -> np.ndarray:
        gram = np.zeros((nv, nv))
        gram[3:6, 3:6] = self.weight[0] * np.eye(3)
        return gram

    def set_reference(self, placement: pin.SE3, velocity: np.ndarray | None = None, acceleration: np.ndarray | None = None) -> None:
        """Reference pose; optional twist and classical acceleration, 6D world axes ``[linear; angular]``."""
        if not isinstance(placement, pin.SE3):
            raise TypeError("the reference of a frame task is a pinocchio.SE3")
        self.reference = pin.SE3(placement)
        self._reference_rotation = np.array(self.reference.rotation)
        self._reference_translation = np.array(self.reference.translation)
        # (_vector copies, so all six rows need no selection: the rates are checked copies.)
        if velocity is not None:
            velocity = _vector(velocity, 6, "frame velocity reference")
            velocity = velocity if self._full else velocity[self.rows]
        if acceleration is not None:
            acceleration = _vector(acceleration, 6, "frame acceleration reference")
            acceleration = acceleration if self._full else acceleration[self.rows]
        self._set_rates(velocity, acceleration, checked=True)

    def write(self, kin: Kinodynamics, rows: np.ndarray, error: np.ndarray, drift: np.ndarray) -> None:
        if self._root:
            rotation = kin.base_rotation
            if self.rows_stale:
                rows[...] = 0.0
                drift[...] = 0.0
                self.rows_stale = False
            if self.reference is None:
                self.set_reference(kin.frame_placement(self.frame_id))
            angular = self._angular_rows
            relative = self._relative
            if self._frame_rotation is None:
                rows[:, 3:6] = rotation if self._all_angular else rotation[angular]
                self._reference_rotation.dot(rotation.T, out=relative)
            else:
                rows[:, 3:6] = rotation[angular]
                self._reference_rotation.dot((rotation @ self._frame_rotation).T, out=relative)
            if self._all_angular:
                error[...] = _log3(relative)
            else:
                error[...] = _log3(relative)[angular]
            return
        if self._full:  # all six rows (a swing foot): no selection, the error written in place
            model, data = kin.model, kin.data
            views = self._placement_views
            if views is None or views[0] is not data or views[1] is None or self.reference is None:
                placement = _update_placement(model, data, self.frame_id)
                if views is None or views[0] is not data:
                    views = self._bind_placement(data, placement)
                if self.reference is None:
                    self.set_reference(placement)
            # (getFrameJacobian writes data.oMf[frame] too, oMi[joint] · placement as
            # updateFramePlacement does: the live views read this tick's placement with no more call.)
            rows[...] = _frame_jacobian(model, data, self.frame_id, LWA)
            drift[...] = _classical_acceleration(model, data, self.frame_id, LWA).vector
            if views[1] is None:  # (the bindings return copies: read the placement)
                np.subtract(self._reference_translation, placement.translation, out=error[:3])
                error[3:] = _log3(self._reference_rotation @ placement.rotation.T)
                return
            halves = self._error_halves
            if halves[0] is not error:  # (the controller passes the same rows every tick)
                halves = self._error_halves = (error, error[:3], error[3:], views[1].T)
            np.subtract(self._reference_translation, views[2], out=halves[1])
            self._reference_rotation.dot(halves[3], out=self._relative)
            halves[2][...] = _log3(self._relative)
            return
        placement = kin.frame_placement(self.frame_id)
        if self.reference is None:
            self.set_reference(placement)
        select = self._select
        rows[...] = kin.frame_jacobian(self.frame_id, LWA)[select]
        drift[...] = kin.frame_drift(self.frame_id, LWA)[select]
        if not self._linear:  # orientation only: the common base / torso task
            error[...] = pin.log3(self._reference_rotation @ placement.rotation.T)[self._angular_rows]
            return
        e = self._error6
        np.subtract(self._reference_translation, placement.translation, out=e[:3])
        if self._angular:
            e[3:] = pin.log3(self._reference_rotation @ placement.rotation.T)
        error[...] = e[select]


    def _bind_placement(self, data: pin.Data, placement: pin.SE3) -> tuple:
        """Views of ``data.oMf[frame]``'s rotation and translation (Pinocchio updates that
        placement in place; ``updateFramePlacement`` returns a copy), checked to be its live
        storage; ``(data, None, None)`` when the bindings return copies."""
        stored = data.oMf[self.frame_id]
        rotation, translation = stored.rotation, stored.translation
        again = data.oMf[self.frame_id]
        live = (
            rotation.ctypes.data == again.rotation.ctypes.data
            and translation.ctypes.data == again.translation.ctypes.data
            and np.array_equal(rotation, placement.rotation)
            and np.array_equal(translation, placement.translation)
        )
        self._placement_views = (data, rotation, translation) if live else (data, None, None)
        self._error_halves = (None,)  # (its Rᵀ view is of these views)
        return self._placement_views


class FramePositionTask(FramePoseTask):
    """Position of a model frame's origin (world axes, 3 rows)."""

    def __init__(self, frame: str, name: str | None = None, **kwargs) -> None:
        super().__init__(frame, name or f"{frame}_position", mask=[1, 1, 1, 0, 0, 0], **kwargs)


class FrameOrientationTask(FramePoseTask):
    """Orientation of a model frame (world axes, 3 rows)."""

    def __init__(self, frame: str, name: str | None = None, **kwargs) -> None:
        super().__init__(frame, name or f"{frame}_orientation", mask=[0, 0, 0, 1, 1, 1], **kwargs)


class PostureTask(WbcTask):
    """Joint positions (the coordinates after the floating base):
    ``q̈_j = ẍ_ref + Kp (q_ref − q_j) + Kd (v_ref − v_j)``. Constant selection Jacobian, zero drift."""

    constant_jacobian = True
    zero_drift = True

    def __init__(
        self,
        name: str = "posture",
        *,
        dim: int | None = None,
        weight: float | np.ndarray = 1.0,
        kp: float | np.ndarray = 0.0,
        kd=None,
        reference: np.ndarray | None = None,
    ) -> None:
        if dim is None and reference is None:
            raise ValueError("give the posture task its dimension or a reference")
        dim = len(reference) if dim is None else dim  # type: ignore[arg-type]
        super().__init__(name, dim, weight=weight, kp=kp, kd=kd)
        self.position_ref: np.ndarray | None = None if reference is None else _vector(reference, dim, "posture reference")
        self.joint_q = slice(0, 0)
        self.joint_v = slice(0, 0)

    def bind(self, kin: Kinodynamics) -> None:
        super().bind(kin)
        if kin.n_joints != self.dim:
            raise ValueError(f"posture task {self.name!r} has {self.dim} rows, the model has {kin.n_joints} joints")
        self.joint_q, self.joint_v = kin.joint_q, kin.joint_v

    def set_reference(self, position: np.ndarray, velocity: np.ndarray | None = None, acceleration: np.ndarray | None = None) -> None:
        self.position_ref = _vector(position, self.dim, "posture reference")
        self._set_rates(velocity, acceleration)

    def write(self, kin: Kinodynamics, rows: np.ndarray, error: np.ndarray, drift: np.ndarray) -> None:
        if self.rows_stale:
            rows[:] = 0.0
            rows[:, self.joint_v] = np.eye(self.dim)
            drift[:] = 0.0
            self.rows_stale = False
        q_joints = kin.q[self.joint_q]
        if self.position_ref is None:
            self.position_ref = np.array(q_joints)
        np.subtract(self.position_ref, q_joints, out=error)


class AngularMomentumTask(WbcTask):
    """Centroidal angular momentum ``L`` (world axes about the CoM, 3 rows):
    ``L̇ = A_ω q̈ + Ȧ_ω v → L̇_ref + Kd (L_ref − L)`` (no position level: ``e = 0``)."""

    def __init__(self, name: str = "angular_momentum", *, weight: float | np.ndarray = 1.0, kd: float | np.ndarray = 10.0) -> None:
        super().__init__(name, 3, weight=weight, kp=0.0, kd=kd)

    def set_reference(self, momentum: np.ndarray, rate: np.ndarray | None = None) -> None:
        """Angular momentum reference (the task's ``v_ref``) and its rate (``ẍ_ref``)."""
        self._set_rates(momentum, rate)

    def write(self, kin: Kinodynamics, rows: np.ndarray, error: np.ndarray, drift: np.ndarray) -> None:
        rows[:] = kin.centroidal_map[3:]
        drift[:] = kin.centroidal_drift[3:]


class ContactForceRegularization:
    """``‖f − f_ref‖²_W`` on every contact's force variables: keeps the redundant contact forces
    (internal squeeze between feet, corner distribution) small and smooth.

    ``reference="weight"`` (default) asks the active contacts to carry the robot's weight: shared
    in proportion to their activations, or — after :meth:`set_support_point` with two contacts —
    split by the lever rule so that the weight is statically supported at that point (the CoM
    target of a balance controller), so the regularisation neither fights gravity nor a commanded
    CoM shift (the shares are computed by :class:`giwbc.control.contact_set.ContactSet`, the lever
    rule by :class:`giwbc.control.contact_set.Lever`). ``"zero"`` regularises towards no force.
    """

    def __init__(self, name: str = "contact_forces", *, weight: float = 1e-5, reference: str = "weight") -> None:
        if reference not in ("weight", "zero"):
            raise ValueError(f"reference must be 'weight' or 'zero', got {reference!r}")
        self.name = name
        self.reference = reference
        self.support_point: np.ndarray | None = None
        self.support_xy: tuple[float, float] | None = None  # its (x, y), as floats
        self.version = 0
        self.set_weight(weight)

    def set_weight(self, weight: float) -> None:
        if not (math.isfinite(weight) and weight >= 0):
            raise ValueError(f"force regularisation weight must be finite and >= 0, got {weight}")
        self.weight = float(weight)
        self.version += 1

    def set_support_point(self, point: np.ndarray | None) -> None:
        """World point (x, y used) whose static support sets the weight split between two contacts."""
        self.support_point = None if point is None else _vector(point, 3, "support point")
        self.support_xy = None if point is None else (float(self.support_point[0]), float(self.support_point[1]))
        self.version += 1

    def __repr__(self) -> str:
        return f"ContactForceRegularization({self.name!r}, weight={self.weight})"
