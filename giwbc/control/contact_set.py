"""The whole-body QP's contact set: each contact's slot in the problem, its force ramp and
activation, and the weight shares the contact-force regularisation asks of them.

A contact keeps its *slot* — its force columns, its 6 motion rows, its friction rows — from the
moment it is added until it is forgotten: breaking a contact ramps its normal-force bound down
(:class:`ContactSlot`), then its motion rows stop constraining the robot and, for a 6D-wrench
contact, pin its wrench at zero (``f = 0``) with its friction rows unbounded — the problem keeps
its size and its KKT system stays regular, so contact switches need no re-layout of the QP and no
cold solve. :class:`ContactSet` owns the slots; the controller (:mod:`giwbc.control.wbc`) owns the
problem and asks the set to lay its slots out, to advance the ramps and assemble the contact
rows each tick, and to keep the force regularisation's gradient up to date.

**Weight shares** (``ContactForceRegularization(reference="weight")``): the active contacts carry
the robot's weight in proportion to their activations; with a support point and exactly two
active contacts, by the lever rule (:class:`Lever`) — the split that statically supports the
weight at that point — each share still scaled by its contact's activation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from giwbc.control.contacts import Contact, WrenchConeContact
from giwbc.control.kinodynamics import LOCAL, Kinodynamics
from giwbc.control.qp import QpProblem
from giwbc.control.tasks import ContactForceRegularization

_frame_jacobian = pin.getFrameJacobian
_classical_acceleration = pin.getFrameClassicalAcceleration


@dataclass(frozen=True, slots=True)
class Lever:
    """The lever rule between two ground points ``p1``, ``p2``: the share of a weight carried at
    ``p1`` when it is statically supported at a point ``s`` — the projection of ``s`` on the
    segment, ``α = ((s − p2)·(p1 − p2)) / ‖p1 − p2‖²`` clipped to ``[0, 1]`` (``p2`` carries ``1 − α``)."""

    x2: float
    y2: float
    dx: float
    dy: float
    norm: float

    @classmethod
    def between(cls, p1: tuple[float, float], p2: tuple[float, float]) -> Lever | None:
        """The lever of two points; ``None`` when they coincide (no split defined)."""
        dx, dy = p1[0] - p2[0], p1[1] - p2[1]
        norm = dx * dx + dy * dy
        return cls(p2[0], p2[1], dx, dy, norm) if norm > 1e-12 else None

    def share(self, px: float, py: float) -> float:
        """``α``: the share of the first point for support at ``(px, py)``."""
        return min(max(((px - self.x2) * self.dx + (py - self.y2) * self.dy) / self.norm, 0.0), 1.0)


@dataclass
class ContactSlot:
    """A contact's place in the problem and its ramp state."""

    contact: Contact
    columns: slice = field(default_factory=lambda: slice(0, 0))
    motion_rows: slice = field(default_factory=lambda: slice(0, 0))
    friction_rows: slice = field(default_factory=lambda: slice(0, 0))
    activation: float = 0.0
    ramp_from: float = 0.0
    ramp_to: float = 1.0
    ramp_time: float = 0.0
    ramp_start: float | None = None  # None: starts at the next tick
    ramping: bool = True  # False once the activation reached ramp_to
    engaged: bool = True  # in contact: its motion rows constrain the robot
    bounds_activation: float = -1.0  # activation the friction bounds were last written for
    in_problem: bool = False  # motion rows currently written (True) or zeroed
    pinned: bool = False  # broken: its force variables held at zero by its motion rows (see ContactSet.disengage)
    closed: bool = False  # made, its normal force capped at 0: its friction rows hold its forces at zero
    ramp_force: float = 0.0  # N: the normal force a ramp moves between 0 and
    unit_index: np.ndarray | None = None  # entries of the force vector carrying normal force
    xy: tuple[float, float] = (0.0, 0.0)  # ground position of the contact reference (cached)
    xy_of: object = None  # the reference placement xy was read from
    unit_value: np.ndarray | None = None  # their share of 1 N of normal force
    last_normal: float = 0.0  # N: the normal force of the last solution
    friction_version: int = -1  # the contact's friction_version its rows in C were written for
    watching: bool = False  # its contact watches for a rolling foot (WrenchConeContact with a detector)
    added_ramp_time: float = 0.0  # the ramp of its last add_contact (what reset() restarts)
    # Views of the problem buffers (set by the layout): motion rows of A, of b, columns of D.
    a_rows: np.ndarray | None = field(default=None, repr=False)
    b_rows: np.ndarray | None = field(default=None, repr=False)
    d_columns: np.ndarray | None = field(default=None, repr=False)

    def normal_limit(self) -> float | None:
        """Cap on the total normal force: none once fully made, ``activation · ramp_force`` else."""
        if not self.ramping and self.ramp_to > 0.0:
            return None
        return self.activation * self.ramp_force

    def start_ramp(self, target: float, duration: float) -> None:
        self.ramp_from, self.ramp_to, self.ramp_time, self.ramp_start = self.activation, target, float(duration), None
        self.ramping = True
        self.engaged = True

    def advance(self, t: float) -> float:
        """Activation at time ``t``; a contact ramped down to zero is no longer engaged."""
        if self.ramp_start is None:
            self.ramp_start = t
        if self.ramp_time <= 0.0:
            progress = 1.0
        else:
            progress = min(max((t - self.ramp_start) / self.ramp_time, 0.0), 1.0)
        self.activation = self.ramp_from + (self.ramp_to - self.ramp_from) * progress
        if progress >= 1.0:
            self.ramping = False
            self.engaged = self.ramp_to > 0.0
        return self.activation


class ContactSet:
    """The contacts of one controller (see the module docstring): slots by name, in the order
    they were added; :meth:`add` / :meth:`remove` / :meth:`forget` at run time."""

    def __init__(self, kin: Kinodynamics) -> None:
        self.kin = kin
        self.slots: dict[str, ContactSlot] = {}
        self.slot_list: list[ContactSlot] = []  # the slots of the last layout, in problem order
        self.weight_force = float(np.linalg.norm(kin.gravity)) * kin.mass  # N, the robot's weight
        self.force_version = -1
        self._force_weight = -1.0
        self._lever: tuple[tuple[int, int], Lever] | None = None
        self._batch: tuple | None = None
        self._problem: QpProblem | None = None
        self._g_force = np.zeros(0)
        self._reg_f = np.zeros(0)

    # --- run-time changes ------------------------------------------------------------------------
    def add(self, contact: Contact, ramp_time: float) -> bool:
        """Make ``contact`` (or re-make a known name), its force bound ramping up over
        ``ramp_time``; True when the problem must be laid out again (a new name, or a different
        number of variables or friction rows)."""
        if not contact.is_bound(self.kin):
            contact.bind(self.kin)
        slot = self.slots.get(contact.name)
        relayout = False
        if slot is None or slot.contact.n_force != contact.n_force or slot.contact.n_ineq != contact.n_ineq:
            activation = 0.0 if slot is None else slot.activation
            slot = ContactSlot(contact, activation=activation)
            self.slots[contact.name] = slot
            self._problem = None  # (laid out again before the next tick)
            relayout = True
        elif slot.contact is not contact:
            slot.contact = contact
            slot.bounds_activation = -1.0
            slot.in_problem = False
            if self._problem is not None:
                self._problem.C[slot.friction_rows, slot.columns] = contact.friction_matrix()
                slot.friction_version = contact.friction_version
        if isinstance(contact, WrenchConeContact):
            contact.reset_support()  # a contact made again stands on its whole sole
        if slot.activation == 0.0:
            contact.reference = None  # re-anchored at the next tick
        slot.ramp_force = self.weight_force
        slot.start_ramp(1.0, ramp_time)
        slot.added_ramp_time = float(ramp_time)
        return relayout

    def remove(self, name: str, ramp_time: float) -> None:
        """Ramp a contact's force bound down to zero over ``ramp_time``, from the load it carries."""
        slot = self.slot(name)
        if slot.ramp_to > 0.0:
            # Ramp down from the load it carries now (its activation scales that from here on).
            slot.ramp_force = slot.last_normal / slot.activation if slot.activation > 0.0 else 0.0
        slot.start_ramp(0.0, ramp_time)

    def forget(self, name: str) -> None:
        """Delete a slot (the problem must be laid out again)."""
        self.slot(name)
        del self.slots[name]
        self._problem = None

    def slot(self, name: str) -> ContactSlot:
        try:
            return self.slots[name]
        except KeyError:
            raise KeyError(f"no contact named {name!r}; contacts: {list(self.slots)}") from None

    def reset(self) -> None:
        """Every contact made again as by its last :meth:`add`: activation 0, ramp restarted,
        reference pose taken at the next tick (the problem must be laid out again)."""
        for name, slot in list(self.slots.items()):
            fresh = ContactSlot(slot.contact)
            fresh.ramp_force = self.weight_force
            fresh.start_ramp(1.0, slot.added_ramp_time)
            fresh.added_ramp_time = slot.added_ramp_time
            slot.contact.reference = None
            self.slots[name] = fresh
        self._problem = None

    # --- layout ------------------------------------------------------------------------------------
    def lay_out_columns(self, nv: int) -> tuple[int, int]:
        """Force columns after the ``nv`` accelerations and 6 motion rows per slot from equality
        row 0; returns ``(variables, motion rows)``."""
        n, eq = nv, 0
        for slot in self.slots.values():
            c = slot.contact
            slot.columns = slice(n, n + c.n_force)
            slot.motion_rows = slice(eq, eq + c.n_motion)
            n, eq = n + c.n_force, eq + c.n_motion
            slot.bounds_activation = -1.0
            slot.pinned = False
            slot.closed = False
            slot.in_problem = not slot.engaged  # a broken contact is pinned again (disengage) at the next tick
        return n, eq

    def lay_out_friction(self, first_row: int) -> int:
        """Friction rows of each slot from inequality row ``first_row``; returns the row after them."""
        ineq = first_row
        for slot in self.slots.values():
            slot.friction_rows = slice(ineq, ineq + slot.contact.n_ineq)
            ineq += slot.contact.n_ineq
        return ineq

    def write_constants(self, C: np.ndarray) -> None:
        """The constant friction matrices into the inequality rows ``C``."""
        for slot in self.slots.values():
            C[slot.friction_rows, slot.columns] = slot.contact.friction_matrix()
            slot.friction_version = slot.contact.friction_version
            c = slot.contact
            slot.watching = isinstance(c, WrenchConeContact) and c.roll is not None

    def bind(self, problem: QpProblem, D: np.ndarray, reg_f: np.ndarray, nv: int) -> None:
        """Views of the laid-out problem: each slot's motion rows (``A``, ``b``), its columns of
        the equation-of-motion block ``D``; the force regularisation's diagonal ``reg_f`` and the
        force part of the gradient; the one-batch assembly when every contact allows it."""
        A, b = problem.A, problem.b
        n = problem.n
        self._problem = problem
        self._g_force = problem.g[nv:]
        self._reg_f = reg_f
        self.force_version = -1
        self._force_weight = -1.0
        self._lever = None
        self.slot_list = list(self.slots.values())
        contacts = [slot.contact for slot in self.slot_list]
        if contacts and all(c.phi is None and c.n_motion == 6 for c in contacts) and len({c.kd for c in contacts}) == 1:
            rows = 6 * len(contacts)
            self._batch = (A[:rows, :nv], b[:rows], D[:, nv:n], contacts[0].kd, np.zeros(rows))
        else:
            self._batch = None
        for slot in self.slot_list:
            slot.a_rows = A[slot.motion_rows, :nv]
            slot.b_rows = b[slot.motion_rows]
            slot.d_columns = D[:, slot.columns]
            unit = slot.contact.nominal_force(1.0)
            nonzero = np.flatnonzero(unit)
            slot.unit_index = nonzero + (slot.columns.start - nv)
            slot.unit_value = unit[nonzero]

    def pattern(self, ac_pattern: np.ndarray, supports: np.ndarray, d_rows: np.ndarray, d_source: np.ndarray, n_eq: int) -> None:
        """Structural non-zeros of the contact rows and columns in ``[A; C]`` (sparse backends)."""
        for slot in self.slots.values():
            cols = supports[slot.contact.joint_id]
            ac_pattern[slot.motion_rows, : supports.shape[1]] = cols
            if slot.contact.n_force == slot.contact.n_motion:  # f = 0 rows of a broken contact
                ac_pattern[slot.motion_rows, slot.columns] = np.eye(slot.contact.n_force, dtype=bool)
            ac_pattern[d_rows, slot.columns] = cols[d_source][:, None]
            rows = slice(n_eq + slot.friction_rows.start, n_eq + slot.friction_rows.stop)
            ac_pattern[rows, slot.columns] = slot.contact.friction_pattern()

    # --- the tick ----------------------------------------------------------------------------------
    def assemble(self, t: float, reg: ContactForceRegularization | None) -> None:
        """Advance the ramps to ``t`` (friction bounds), write every engaged contact's motion rows
        and ``−JᵀΦ`` columns, pin the broken ones, and update the force regularisation."""
        p = self._problem
        kin = self.kin
        force_changed = closed_changed = False
        batch = self._batch
        for slot in self.slot_list:
            c = slot.contact
            if slot.ramping or slot.bounds_activation < 0.0:
                activation = slot.advance(t)
                if activation != slot.bounds_activation:
                    rows = slot.friction_rows
                    c.friction_bounds(p.l[rows], p.u[rows], slot.normal_limit())  # type: ignore[union-attr]
                    slot.bounds_activation = activation
                    force_changed = True
                closed = slot.engaged and slot.normal_limit() == 0.0
                if closed != slot.closed:
                    slot.closed = closed
                    closed_changed = True
            if slot.engaged:
                if slot.pinned:
                    self.reengage(slot)
                if c.reference is None:
                    c.reference = c.placement_in_world(kin)
                elif slot.watching and slot.ramp_to > 0.0:
                    c.watch(kin, t)  # type: ignore[attr-defined]
                if c.friction_version != slot.friction_version:
                    self._rewrite_friction(slot)
                    force_changed = True
                if batch is not None and (c.kd != batch[3] or c.kp != 0.0):
                    batch = None
            else:
                batch = None
        if closed_changed:
            self._declare_fixed()
        if batch is not None:
            self._assemble_batch(kin, batch)
        else:
            for slot in self.slot_list:
                c = slot.contact
                if slot.engaged:
                    c.assemble(kin, slot.a_rows, slot.b_rows, slot.d_columns)
                    slot.in_problem = True
                elif slot.in_problem:
                    self.disengage(slot)

        # The force regularisation (constant between ramps and support-point moves).
        if force_changed:
            self._lever = None
        if force_changed or (reg is not None and reg.version != self.force_version) or (reg is None and self.force_version != -1):
            self.update_force_regularization(reg)

    def _rewrite_friction(self, slot: ContactSlot) -> None:
        """A contact's friction rows after its support changed (a rolling foot): the matrix and
        the bounds, in place (same rows)."""
        p = self._problem
        c = slot.contact
        rows = slot.friction_rows
        p.C[rows, slot.columns] = c.friction_matrix()  # type: ignore[union-attr]
        c.friction_bounds(p.l[rows], p.u[rows], slot.normal_limit())  # type: ignore[union-attr]
        slot.bounds_activation = slot.activation
        slot.friction_version = c.friction_version

    def disengage(self, slot: ContactSlot) -> None:
        """A broken contact keeps its slot: its motion rows no longer constrain the robot and,
        when it has as many force variables as motion rows (a 6D wrench), they become ``f = 0``
        instead of zero rows, its friction rows unbounded — a regular KKT system (zero rows and
        the 16 cone faces meeting at ``f = 0`` would make every tick's first solve singular)."""
        p = self._problem
        p.A[slot.motion_rows] = 0.0  # type: ignore[union-attr]
        slot.b_rows[...] = 0.0  # type: ignore[index]
        slot.d_columns[...] = 0.0  # type: ignore[index]
        slot.in_problem = False
        slot.contact.reference = None
        if slot.contact.n_force == slot.contact.n_motion:
            p.A[slot.motion_rows, slot.columns] = np.eye(slot.contact.n_force)  # type: ignore[union-attr]
            rows = slot.friction_rows
            p.l[rows] = -np.inf  # type: ignore[union-attr]
            p.u[rows] = np.inf  # type: ignore[union-attr]
            slot.bounds_activation = math.nan  # (rewritten when it is made again)
            slot.pinned = True
            self.force_version = -2  # the force regularisation's gradient is recomputed
            self._declare_fixed()

    def reengage(self, slot: ContactSlot) -> None:
        """Undo :meth:`disengage`'s ``f = 0`` rows and unbounded friction rows."""
        p = self._problem
        p.A[slot.motion_rows, slot.columns] = 0.0  # type: ignore[union-attr]
        slot.contact.friction_bounds(p.l[slot.friction_rows], p.u[slot.friction_rows], slot.normal_limit())  # type: ignore[union-attr]
        slot.bounds_activation = slot.activation
        slot.pinned = False
        self._declare_fixed()

    def _declare_fixed(self) -> None:
        """Tell the problem which variables the pinned and the closed slots hold at zero
        (``QpProblem.fixed``: a KKT solver eliminates them — in single support, the swing foot's
        6 wrench variables and their 6 rows, a 12-row smaller system). A closed slot — made, its
        normal force capped at 0, at a touch-down's first tick — keeps its motion rows: its
        friction rows hold its forces at zero (a friction cone closed at its apex; its faces,
        all tight there, a degenerate active set), declared with them instead of unit rows."""
        pinned = [slot for slot in self.slot_list if slot.pinned]
        closed = [slot for slot in self.slot_list if slot.closed and not slot.pinned]
        if not pinned and not closed:
            self._problem.fixed = None  # type: ignore[union-attr]
            return
        columns = np.concatenate([np.arange(slot.columns.start, slot.columns.stop) for slot in pinned + closed])
        rows = np.concatenate([np.arange(slot.motion_rows.start, slot.motion_rows.stop) for slot in pinned] or [np.zeros(0, dtype=np.int64)])
        if not closed:
            self._problem.fixed = (columns, rows)  # type: ignore[union-attr]
            return
        dead = np.concatenate([np.arange(slot.friction_rows.start, slot.friction_rows.stop) for slot in closed])
        self._problem.fixed = (np.sort(columns), rows, dead)  # type: ignore[union-attr]

    def _assemble_batch(self, kin: Kinodynamics, batch: tuple) -> None:
        """:meth:`Contact.assemble` for all contacts at once, when every one is engaged, has the
        6D wrench as variables (``Φ = I``), the same ``kd`` and no ``kp`` (the balance
        controller's feet): their motion rows and force columns are then contiguous, so the
        twist, the damping and ``−Jᵀ`` are one numpy call each for all of them."""
        motion, rhs, columns, kd, twist = batch
        model, data, v = kin.model, kin.data, kin.v
        rows = 0
        for slot in self.slot_list:
            c = slot.contact
            J = c.jacobian = _frame_jacobian(model, data, c.joint_id, c.placement, LOCAL)
            c.drift = _classical_acceleration(model, data, c.joint_id, c.placement, LOCAL).vector
            motion[rows : rows + 6] = J
            rows += 6
        motion.dot(v, out=twist)
        np.multiply(twist, -kd, out=rhs)
        rows = 0
        for slot in self.slot_list:
            rhs[rows : rows + 6] -= slot.contact.drift
            rows += 6
        np.negative(motion.T, out=columns)
        for slot in self.slot_list:
            slot.in_problem = True

    def wrenches(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """Each contact with non-zero activation: its 6D contact-frame wrench in the solution ``x``
        (its normal force remembered for a later ramp-down)."""
        wrenches = {}
        for slot in self.slot_list:
            if slot.activation > 0.0:
                forces = x[slot.columns]
                phi = slot.contact.phi
                wrench = wrenches[slot.contact.name] = forces if phi is None else phi @ forces
                slot.last_normal = wrench[2]
        return wrenches

    # --- force regularisation ------------------------------------------------------------------------
    def update_force_regularization(self, reg: ContactForceRegularization | None) -> None:
        """Gradient of ``w ‖f − f_ref‖²`` (and its diagonal): called when activations, the weight
        or the support point change — at every tick while a balance controller moves its CoM
        target, so the common case (two fully active contacts, only the point moved) is a few
        float operations and scalar writes."""
        g = self._g_force
        weight = 0.0 if reg is None else reg.weight
        lever = self._lever
        if lever is not None and reg is not None and weight == self._force_weight and reg.support_xy is not None:
            # (the lever is dropped whenever an activation changes)
            (i1, i2), rule = lever
            px, py = reg.support_xy
            alpha = rule.share(px, py)
            scale = -weight * self.weight_force
            g[i1] = scale * alpha
            g[i2] = scale * (1.0 - alpha)
            self.force_version = reg.version
            return
        if reg is None or reg.version != self.force_version or self._force_weight != weight:
            self._reg_f[:] = weight
            self._force_weight = weight
        self.force_version = -1 if reg is None else reg.version
        shares = self.shares(reg) if reg is not None and reg.reference == "weight" and weight > 0 else None
        scale = -weight * self.weight_force
        for i, slot in enumerate(self.slot_list):
            share = 0.0 if shares is None else shares[i]
            if len(slot.unit_index) == 1:  # type: ignore[arg-type]
                g[slot.unit_index[0]] = scale * share  # type: ignore[index]
            else:
                g[slot.unit_index] = (scale * share) * slot.unit_value  # type: ignore[operator]
        # Remember the lever for the fast path: two fully active single-entry contacts.
        self._lever = None
        activations = [slot.activation for slot in self.slot_list]
        active = [i for i, value in enumerate(activations) if value > 0.0]
        if shares is not None and len(active) == 2 and all(activations[i] == 1.0 for i in active):
            s1, s2 = (self.slot_list[i] for i in active)
            if len(s1.unit_index) == 1 and len(s2.unit_index) == 1 and s1.contact.reference is not None and s2.contact.reference is not None:  # type: ignore[arg-type]
                rule = Lever.between(self.contact_xy(s1), self.contact_xy(s2))
                if rule is not None:
                    self._lever = ((int(s1.unit_index[0]), int(s2.unit_index[0])), rule)  # type: ignore[index]

    def shares(self, reg: ContactForceRegularization) -> list[float]:
        """Weight share of each contact: by activation, or by the lever rule about the support
        point when exactly two contacts are active."""
        slots = self.slot_list
        activations = [slot.activation for slot in slots]
        total = sum(activations)
        if total <= 0.0:
            return [0.0] * len(slots)
        shares = [a / total for a in activations]
        point = reg.support_point
        active = [i for i, a in enumerate(activations) if a > 0.0]
        if point is not None and len(active) == 2:
            i, j = active
            rule = Lever.between(self.contact_xy(slots[i]), self.contact_xy(slots[j]))
            if rule is not None:
                alpha = rule.share(point[0], point[1])
                a1, a2 = alpha * activations[i], (1.0 - alpha) * activations[j]
                if a1 + a2 > 0.0:
                    shares[i], shares[j] = a1 / (a1 + a2), a2 / (a1 + a2)
        return shares

    def contact_xy(self, slot: ContactSlot) -> tuple[float, float]:
        """Ground position of a contact: where it was made (cached), or where it is now."""
        reference = slot.contact.reference
        if reference is None:
            translation = slot.contact.placement_in_world(self.kin).translation
            return float(translation[0]), float(translation[1])
        if slot.xy_of is not reference:
            slot.xy = (float(reference.translation[0]), float(reference.translation[1]))
            slot.xy_of = reference
        return slot.xy
