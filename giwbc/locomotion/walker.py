"""Walking and push recovery by stepping, on the balance controller's whole-body QP.

Each WBC tick :meth:`WalkingController.update`:

1. measures the CoM, its velocity and the DCM ``ξ = c + ċ/ω`` (Pinocchio, from ``(q, v)``);
2. advances the **contact schedule**: double support → (the swing foot's contact ramped out with
   the WBC's force ramp) → single support → touch-down (the contact made again, its force ramped
   in) → double support … Touch-down is *early* when the foot's measured normal force exceeds a
   threshold after ``early_touchdown`` of the swing, *late* when it has not by the planned time
   (the foot keeps descending, for at most ``late_touchdown`` s);
3. in single support, the **step adapter** moves the landing spot and the touch-down time from
   the measured DCM, and the **swing trajectory** is re-targeted (continuous in flight);
4. sets the WBC references: the CoM task's horizontal acceleration from the **DCM controller**
   (``c̈ = ω² (c − p*)``, ``p*`` the CoP it asks for, clipped into the support polygon), its height
   held; the swing sole's SE3 pose task; the pelvis heading from the feet; the force
   regularisation's support point at ``p*``;
5. runs the WBC.

Standing, a push whose capture point leaves the support polygon (by ``push_margin``) starts
recovery steps — the foot on the side of the push steps to where the step adapter puts it —
until the capture point is back inside; then it settles in double support. A velocity command
(:meth:`set_command`) walks; the command going back to zero brings the feet together and stops.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from giwbc.control.balance import BalanceConfig, BalanceController
from giwbc.control.contacts import Contact
from giwbc.control.tasks import FramePoseTask
from giwbc.control.wbc import WbcResult
from giwbc.locomotion.dcm import CopSegment, DcmController, DcmReference, walking_cop_plan
from giwbc.locomotion.footsteps import Footstep, FootstepPlanner, GaitConfig, VelocityCommand, other_side, side_sign, wrap_angle
from giwbc.locomotion.lipm import cop_start_for_dcm, natural_frequency
from giwbc.locomotion.step_adapter import DcmErrorShaper, StepAdapter, StepAdapterWeights, bounded_box
from giwbc.locomotion.support import clip_to_polygon, convex_hull, signed_distance, sole_corners
from giwbc.locomotion.swing import SwingTrajectory
from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import Robot


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """``‖a − b‖`` of two (x, y) points, as ``np.linalg.norm`` computes it (``√(dx² + dy²)``), on floats."""
    dx, dy = float(a[0]) - float(b[0]), float(a[1]) - float(b[1])
    return math.sqrt(dx * dx + dy * dy)


class Phase(enum.Enum):
    STAND = "stand"  # double support, no step planned
    DOUBLE = "double"  # double support between steps
    SINGLE = "single"  # one foot swinging


@dataclass(frozen=True)
class WalkerConfig:
    """Gait, gains and switching thresholds of :class:`WalkingController`."""

    gait: GaitConfig = field(default_factory=GaitConfig)
    # proxsuite gets 20 outer iterations (default 10): the ticks of a contact switch need more
    balance: BalanceConfig = field(default_factory=lambda: BalanceConfig(min_normal_force=5.0, solver_settings={"max_iter": 20}))
    com_height: float | None = None  # m above the soles; default: the standing pose's
    dcm_gain: float = 5.0  # s⁻¹, walking
    standing_dcm_gain: float = 8.0  # s⁻¹, standing (stiffer: feet-in-place balance)
    com_height_kp: float = 100.0
    swing_apex: float = 0.07  # m
    swing_weight: float = 2.0  # walking: low, the CoM task keeps the priority
    recovery_swing_weight: float = 10.0  # recovering from a push: the foot must get there
    swing_kp: float = 400.0
    contact_ramp: float = 0.04  # s, force ramp at lift-off and touch-down
    start_shift: float = 0.3  # s, double support before the first step (weight shift)
    preview_steps: int = 3
    touchdown_force: float = 0.15  # fraction of the weight on the swing foot meaning "landed"
    early_touchdown: float = 0.6  # fraction of the swing after which contact means touch-down
    touchdown_distance: float = 0.05  # m: an early contact this close to the landing spot is a touch-down
    late_touchdown: float = 0.08  # s, how long past the plan the foot may keep descending
    descent_speed: float = 0.25  # m/s, of a late foot
    touchdown_depth: float = 0.003  # m, the swing aims this far below the ground
    step_adaptation: bool = True
    # On an *estimated* DCM (deployment): the adapter sees the step's own nominal DCM reference
    # plus the error beyond ``adapt_deadband`` (m), low-passed over ``adapt_filter`` (s), and moves
    # a landing at most ``max_adjustment`` (m, each axis of the stance frame) from the plan:
    # estimation noise leaves the nominal steps alone, a push still moves them.
    adapt_deadband: float = 0.0
    adapt_filter: float = 0.0
    max_adjustment: float = math.inf
    # Single support without the swing foot's (force-less) contact slot: a smaller QP each
    # single-support tick, at the price of a re-layout and cold solve at lift-off and touch-down.
    drop_swing_contact: bool = False
    adapter: StepAdapterWeights = field(default_factory=StepAdapterWeights)
    min_swing: float = 0.22  # s, shortest single support the adapter may choose
    max_swing: float = 0.5  # s, longest
    landing_box: tuple[tuple[float, float], tuple[float, float]] = ((-0.38, 0.45), (0.17, 0.65))  # stance frame, left foot
    replan_distance: float = 0.01  # m: the DCM reference is re-planned when the landing spot moved this much ...
    replan_time: float = 0.01  # s: ... or the touch-down time this much
    anchor_tolerance: float = 0.08  # m: plan from the nominal footholds while the real ones are this close
    push_margin: float = 0.0  # m: step when the capture point is this far outside the polygon
    disturbance_time: float = 0.02  # s, low-pass of the DCM rate for the disturbance estimate
    use_disturbance: bool = True  # choosing the recovery stance: predict the DCM with the estimated disturbance held ...
    disturbance_horizon: float = 0.1  # s: ... this much longer (a push lasts a while)
    settle_margin: float = 0.02  # m: after a recovery step, settle once the capture point is this far inside
    stiff_swing_error: float = 0.08  # m: a DCM error this large in a swing makes the swing foot task stiff
    hurry_error: float = 0.1  # m: a DCM error this large at touch-down cuts the double support short
    recovery_offset: float = 0.05  # m: the recovering foot lands this far outward of the capture point
    # Standing: step when the capture point *plus the disturbance lead* (a push still acting) leaves
    # the polygon — ~0.05 s sooner than the capture point alone (150 N, tuning seeds 0-39: with the
    # wider recovery box 29/40 vs 25/40; the wider box alone 18/40, a narrower one 16/40).
    trigger_lead: bool = True
    lead_settle_time: float = 0.5  # s after a walk stops: the capture point alone decides (the stop's own transient reads as a push)
    recovery_landing_box: tuple[tuple[float, float], tuple[float, float]] | None = ((-0.45, 0.5), (0.17, 0.75))  # standing recovery's (None: landing_box)
    # Where a recovering step's adapter holds the CoP: "edge" (the stance sole's point nearest the
    # DCM, where the DCM controller clips it), "centre" (the sole centre), or "auto" (the edge, but
    # the centre when the edge's landing is on the box's *forward* bound: the DCM then overshoots
    # the reachable front more, and the adapter lands the saturated step sooner). Forward pushes
    # at 150 N (|direction| <= 30 deg, tuning seeds 100-299): 30/41 vs 25/41 with the edge, the
    # other directions the same. (Applied at every bound: forward 37/41, but back-diagonal pushes
    # lost as much, 11 vs 21/28.)
    recovery_cop: str = "auto"
    # A recovering step *backward* reaches farther than a standing pelvis allows: the knee straight,
    # the sole still ~3 cm up at the planned touch-down, the foot lands ~0.05-0.08 s late and ~0.1 m
    # past its spot, and the split collapses (150 N, tuning seeds 100-299: 29 of the 69 falls). While
    # such a foot swings, the CoM height reference drops so that the swing hip is within
    # ``recovery_reach`` × the straight leg's length of the landing spot (0: off), by at most
    # ``recovery_max_crouch`` m, held until the recovery ends. (Backward only: for every direction,
    # forward and sideways steps got worse, 104 vs 102 of 154 overall — lowering the CoM fast unloads
    # the feet just when the CoP must push; a fixed 5 cm crouch: 123 vs 131/200; a lower swing apex,
    # a shorter minimum swing: within noise.) Not yet for a push straight backward: 150 N at 180 deg,
    # seeds 0-29, 16/30 vs 22/30 without (at 165 deg 15/20 vs 3/20, at -165 deg 20/20 both).
    recovery_reach: float = 0.97
    recovery_max_crouch: float = 0.12

    def __post_init__(self) -> None:
        if self.preview_steps < 1:
            raise ValueError("preview_steps must be >= 1")
        if not (0.0 < self.min_swing <= self.gait.single_support <= self.max_swing):
            raise ValueError("need 0 < min_swing <= single_support <= max_swing")
        if self.contact_ramp < 0 or self.contact_ramp >= self.gait.double_support + 1e-12 and self.contact_ramp > 0.5:
            raise ValueError("contact_ramp must be >= 0 and short")
        if not (self.adapt_deadband >= 0.0 and self.adapt_filter >= 0.0 and self.max_adjustment > 0.0) or not math.isfinite(self.adapt_deadband + self.adapt_filter):
            raise ValueError(f"need finite adapt_deadband, adapt_filter >= 0 and max_adjustment > 0, got {self.adapt_deadband}, {self.adapt_filter}, {self.max_adjustment}")
        if not (0.0 <= self.recovery_reach <= 1.0):
            raise ValueError(f"recovery_reach must be in [0, 1] (a fraction of the straight leg), got {self.recovery_reach}")
        if not (0.0 <= self.recovery_max_crouch < 0.5):
            raise ValueError(f"recovery_max_crouch must be in [0, 0.5) m, got {self.recovery_max_crouch}")
        if self.recovery_cop not in ("edge", "centre", "auto"):
            raise ValueError(f"recovery_cop must be 'edge', 'centre' or 'auto', got {self.recovery_cop!r}")
        if not (self.lead_settle_time >= 0.0 and math.isfinite(self.lead_settle_time)):
            raise ValueError(f"lead_settle_time must be finite and >= 0, got {self.lead_settle_time}")
        for name in ("landing_box", "recovery_landing_box"):
            box = getattr(self, name)
            if box is None and name == "recovery_landing_box":
                continue
            (x_lo, x_hi), (y_lo, y_hi) = box
            if not (x_lo < x_hi and 0.0 < y_lo < y_hi) or not all(math.isfinite(float(x)) for x in (x_lo, x_hi, y_lo, y_hi)):
                raise ValueError(f"{name} must be ((x_lo, x_hi), (y_lo, y_hi)) with x_lo < x_hi and 0 < y_lo < y_hi (left foot, stance frame), got {box}")


@dataclass
class WalkerState:
    """What the walker did at the last tick (for logs, tests and benchmarks)."""

    phase: Phase = Phase.STAND
    stance: str = "left"
    dcm: np.ndarray = field(default_factory=lambda: np.zeros(2))
    dcm_ref: np.ndarray = field(default_factory=lambda: np.zeros(2))
    cop: np.ndarray = field(default_factory=lambda: np.zeros(2))
    disturbance: np.ndarray = field(default_factory=lambda: np.zeros(2))  # ξ̇ − ω (ξ − p), m/s
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    com_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    steps: int = 0  # touch-downs so far
    recovery_steps: int = 0
    early_touchdowns: int = 0
    late_touchdowns: int = 0
    notes: list[str] = field(default_factory=list)
    # The swing target before and after the step residual (:meth:`WalkingController.set_step_residual`).
    planned_target: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    target: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    nominal_target: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))  # the plan's, before the step adapter


class WalkingController:
    """Walking / stepping on a :class:`BalanceController`'s WBC (see the module docstring)."""

    def __init__(self, description: RobotDescription, config: WalkerConfig | None = None, model: pin.Model | None = None) -> None:
        self.config = config = config or WalkerConfig()
        self.description = description
        self.balance = BalanceController(description, config.balance, model)
        self.wbc = self.balance.wbc
        self.model = self.wbc.model
        self._data = self.model.createData()
        contacts = {c.name: c for c in self.balance.contacts}
        self.contacts: dict[str, Contact] = {}
        for side in ("left", "right"):
            matches = [c for name, c in contacts.items() if name.startswith(side)]
            if len(matches) != 1:
                raise ValueError(f"walking needs one foot contact per side named left_*/right_*, got {list(contacts)}")
            self.contacts[side] = matches[0]
        # The swing sole's pose task: in the QP only while that foot swings (no cost otherwise).
        self.swing_tasks = {
            side: FramePoseTask(contact.link, f"{side}_swing", weight=config.swing_weight, kp=config.swing_kp) for side, contact in self.contacts.items()
        }
        self._sole = {side: pin.SE3(c.offset) for side, c in self.contacts.items()}
        self._sole_inverse = {side: c.offset.inverse() for side, c in self.contacts.items()}
        self._hips, self._leg_length = self._leg_geometry()
        self.weight = description.total_mass * 9.81
        self.planner = FootstepPlanner(config.gait)
        self.command = VelocityCommand()
        self._in_place = False
        self.state = WalkerState()
        self._com_height: float | None = None
        self.omega = 0.0
        self.adapter: StepAdapter | None = None
        self.dcm_controller: DcmController | None = None
        self._anchored = False
        self.last_result: WbcResult | None = None  # the last tick's
        self._clear_residuals()

    def _leg_geometry(self) -> tuple[dict[str, int], float]:
        """Each leg's first joint below the floating base (the hip) and the hip-to-sole distance
        with every joint at zero (straight legs; the shorter leg's)."""
        model = self.model
        data = model.createData()
        pin.forwardKinematics(model, data, pin.neutral(model))
        hips, lengths = {}, []
        for side, contact in self.contacts.items():
            joint = contact.joint_id
            while model.parents[joint] > 1:
                joint = model.parents[joint]
            hips[side] = joint
            sole = data.oMi[contact.joint_id] * contact.placement
            lengths.append(float(np.linalg.norm(sole.translation - data.oMi[joint].translation)))
        return hips, min(lengths)

    # --- commands ------------------------------------------------------------------------------
    def set_command(self, vx: float = 0.0, vy: float = 0.0, yaw_rate: float = 0.0, *, step_in_place: bool = False) -> list[str]:
        """Walk at ``(vx, vy, yaw_rate)`` (body frame); all zero stops, unless ``step_in_place``.
        A non-finite command raises ``ValueError``; one beyond the gait limits is clamped — the
        notes say how (also kept in ``state.notes``)."""
        clamped = self.planner.clamp(VelocityCommand(vx, vy, yaw_rate))
        self.command = clamped.command
        self._in_place = bool(step_in_place)
        self.state.notes.extend(clamped.notes)
        return clamped.notes

    @property
    def walking(self) -> bool:
        return self._in_place or not self.command.is_zero

    # --- set-up ----------------------------------------------------------------------------------
    def reset(self, q: np.ndarray | None = None) -> None:
        """Stand at configuration ``q`` (default pose): the balance controller's reset, feet where
        they are, no step planned."""
        q = self.description.default_configuration() if q is None else np.asarray(q, dtype=float)
        self.balance.reset(q)
        for task in self.swing_tasks.values():
            self._remove_swing_task(task)
        self._polygons: dict[tuple[str, ...], np.ndarray] = {}
        self._heading = math.nan
        self._com_kp = self.config.com_height_kp
        self.balance.com_task.set_gains(self._com_kp, np.array([0.0, 0.0, 2.0 * math.sqrt(self._com_kp)]))
        self._measure(q, np.zeros(self.model.nv))
        self.feet = {side: self._measured_foot(side) for side in self.contacts}
        ground = float(np.mean([self._sole_world(side).translation[2] for side in self.contacts]))
        self._ground = ground
        self._com_height = float(self._com[2] - ground) if self.config.com_height is None else float(self.config.com_height)
        self.omega = natural_frequency(self._com_height)
        self.adapter = StepAdapter(self.omega, self.config.adapter)
        self.dcm_controller = DcmController(self.omega, self.config.standing_dcm_gain)
        self.command = VelocityCommand()
        self._in_place = False
        self.state = WalkerState()
        self._phase = Phase.STAND
        self._phase_start = 0.0
        self._phase_end = math.inf
        self._stance = "left"
        self._lift_off_issued = False
        self._swing: SwingTrajectory | None = None
        self._target: Footstep | None = None
        self._nominal_offset = np.zeros(2)
        self._nominal_target: Footstep | None = None
        self._step_reference: DcmReference | None = None
        self._dcm_shaper = DcmErrorShaper(self.config.adapt_deadband, self.config.adapt_filter)
        self._recovering = False
        self._crouch = 0.0
        self._lead_after = -math.inf
        self._xi_previous: np.ndarray | None = None
        self._xi_rate: np.ndarray | None = None
        self._last_cop: np.ndarray | None = None
        self._last_tick = 0.0
        self._nominal_feet: dict[str, Footstep] = {}
        self._planned_for: tuple[np.ndarray, float] | None = None
        self._reference: DcmReference | None = None
        self._time = 0.0
        self._anchored = True
        self._clear_residuals()

    # --- measurements ------------------------------------------------------------------------------
    def _measure(self, q: np.ndarray, v: np.ndarray) -> None:
        data = self._data
        pin.centerOfMass(self.model, data, q, v, False)
        self._com = np.array(data.com[0])
        self._com_velocity = np.array(data.vcom[0])

    def _sole_world(self, side: str) -> pin.SE3:
        contact = self.contacts[side]
        return self._data.oMi[contact.joint_id] * contact.placement

    def _measured_foot(self, side: str) -> Footstep:
        placement = self._sole_world(side)
        rotation = placement.rotation
        return Footstep(side, placement.translation[:2].copy(), math.atan2(rotation[1, 0], rotation[0, 0]))

    def support_polygon(self, sides: tuple[str, ...] | None = None) -> np.ndarray:
        """CCW hull of the soles in contact (both in double support) at their planned holds."""
        sides = tuple(self.contacts) if sides is None else sides
        cached = self._polygons.get(sides)
        if cached is not None:
            return cached
        corners = []
        for side in sides:
            contact = self.contacts[side]
            foot = self.feet[side]
            corners.append(sole_corners(foot.position, foot.yaw, contact.half_length, contact.half_width))  # type: ignore[attr-defined]
        hull = self._polygons[sides] = convex_hull(np.vstack(corners))
        return hull

    # --- the tick ----------------------------------------------------------------------------------
    def update(self, q: np.ndarray, v: np.ndarray, t: float, foot_forces: dict[str, float] | None = None) -> WbcResult:
        """One tick at time ``t`` for the Pinocchio state ``(q, v)``; ``foot_forces`` are the
        measured normal forces (N) per side (``None``: switch on the schedule alone).

        A non-finite state plans nothing (the schedule and the references wait) and returns the
        WBC's fallback command (``WbcStatus.INVALID_STATE``, with its message, counted in
        ``wbc.failures``); it never raises. Wrong shapes raise ``ValueError``."""
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if not math.isfinite(float(q.sum() + v.sum())):
            self.last_result = self.wbc.update(q, v, t)
            return self.last_result
        if not self._anchored:
            self.reset(q)
        self._time = t = float(t)
        self._measure(q, v)
        omega = self.omega
        com, com_velocity = self._com, self._com_velocity
        xi = np.array([com[0] + com_velocity[0] / omega, com[1] + com_velocity[1] / omega])
        self._estimate_disturbance(t, xi)
        self.state.dcm = xi
        self._advance(t, xi, foot_forces or {})
        xi_ref, xi_rate_ref, support = self._references(t, xi)
        if self._dcm_offset is not None:
            xi_ref = xi_ref + self._dcm_offset
        controller = self.dcm_controller
        controller.gain = self.config.standing_dcm_gain if self._phase is Phase.STAND else self.config.dcm_gain
        cop = controller.desired_cop(xi, xi_ref, xi_rate_ref, support)
        self._last_cop = cop
        acceleration = controller.com_acceleration(self._com, cop)
        # The CoM task's horizontal rows have no damping (set in reset): their position error
        # carries the acceleration, ẍ* = kp (c + c̈/kp − c) = c̈ — one reference, no rates to gather.
        kp = self._com_kp
        self.balance.com_task.set_reference(np.array([self._com[0] + acceleration[0] / kp, self._com[1] + acceleration[1] / kp, self._ground + self._com_height + self._height_offset - self._recovery_drop()]))
        if self._phase is not Phase.SINGLE:  # (one foot: it carries the weight, no split to set)
            self.balance.force_regularization.set_support_point(np.array([cop[0], cop[1], 0.0]))
        self._heading_reference()
        self.state.dcm_ref, self.state.cop = xi_ref, cop
        self.state.com, self.state.com_velocity = self._com, self._com_velocity
        self.state.phase, self.state.stance = self._phase, self._stance
        self.last_result = self.wbc.update(q, v, t)
        return self.last_result

    def _recovery_drop(self) -> float:
        """How far the CoM height reference is lowered now (m): while a recovering foot swings
        backward, enough to keep its landing spot within reach; held until the recovery ends."""
        cfg = self.config
        if not self._recovering:
            self._crouch = 0.0
            return 0.0
        if cfg.recovery_reach > 0.0 and self._phase is Phase.SINGLE and self._target is not None:
            hip = self._data.oMi[self._hips[other_side(self._stance)]].translation
            reach = cfg.recovery_reach * self._leg_length
            dx, dy = float(self._target.position[0]) - float(hip[0]), float(self._target.position[1]) - float(hip[1])
            if dx * math.cos(self._heading) + dy * math.sin(self._heading) < 0.0:  # behind the hip
                height = math.sqrt(max(reach * reach - dx * dx - dy * dy, 0.0))
                self._crouch = min(max(self._crouch, float(hip[2]) - self._ground - height), cfg.recovery_max_crouch)
        return self._crouch

    def _estimate_disturbance(self, t: float, xi: np.ndarray) -> None:
        """What the LIPM does not explain: ``d = ξ̇ − ω (ξ − p)`` (m/s), ``ξ̇`` the DCM's measured
        rate (low-passed over ``disturbance_time``), ``p`` the CoP asked for at the last tick. A
        push shows up here at once (``F / (m ω)``) — the capture point alone only shows what it
        has done so far."""
        previous, last = self._xi_previous, self._last_tick
        self._xi_previous, self._last_tick = xi, t
        if previous is None or self._last_cop is None or not t > last:
            return
        # (Plain floats, element by element: the same operations as on the 2-vectors.)
        dt = t - last
        alpha = dt / (self.config.disturbance_time + dt)
        smoothed = self._xi_rate
        rates = []
        for i in (0, 1):
            rate = (float(xi[i]) - float(previous[i])) / dt
            rates.append(rate if smoothed is None else float(smoothed[i]) + alpha * (rate - float(smoothed[i])))
        self._xi_rate = np.array(rates)
        omega, cop = self.omega, self._last_cop
        self.state.disturbance = np.array([rates[i] - omega * (float(previous[i]) - float(cop[i])) for i in (0, 1)])

    def _disturbance_lead(self) -> np.ndarray:
        """The DCM shift a disturbance ``d`` held for ``disturbance_horizon`` more seconds adds to
        any later prediction: with the CoP held at ``p``, ``ξ(T) = p + (ξ + (d/ω)(1 − e^{−ωτ}) − p) e^{ωT}``
        for ``T ≥ τ`` — the measured DCM plus this lead, in the same closed form."""
        cfg = self.config
        if not cfg.use_disturbance:
            return np.zeros(2)
        return self.state.disturbance / self.omega * (1.0 - math.exp(-self.omega * cfg.disturbance_horizon))

    def step(self, robot: Robot) -> WbcResult:
        """Read ``robot`` (state, foot forces), run one tick, command its joint torques."""
        q, v = robot.generalized_state()
        forces = {side: float(robot.contact_wrench(contact.link).force[2]) for side, contact in self.contacts.items()}
        result = self.update(q, v, robot.time(), forces)
        robot.set_joint_torques(result.tau)
        return result

    # --- schedule ----------------------------------------------------------------------------------
    def _advance(self, t: float, xi: np.ndarray, forces: dict[str, float]) -> None:
        cfg = self.config
        if self._phase is Phase.STAND:
            if self.walking:
                first = self.planner.first_swing_side(self.command)
                self._begin_double(t, stance=other_side(first), duration=cfg.start_shift)
            elif signed_distance(xi + self._disturbance_lead() if cfg.trigger_lead and t >= self._lead_after else xi, self.support_polygon()) > cfg.push_margin:
                swing = self._recovery_swing_side(xi)
                self._recovering = True
                self._nominal_feet = {}
                self._begin_double(t, stance=other_side(swing), duration=max(cfg.contact_ramp, 1e-3))
                self.state.recovery_steps += 1
            return
        if self._phase is Phase.DOUBLE:
            swing = other_side(self._stance)
            if not self._lift_off_issued and t >= self._phase_end - cfg.contact_ramp:
                self.wbc.remove_contact(self.contacts[swing].name, ramp_time=cfg.contact_ramp)
                self._lift_off_issued = True
            if t >= self._phase_end and self._lift_off_issued and self.wbc.contact_activation(self.contacts[swing].name) == 0.0:
                self._begin_single(t)
            return
        # Single support.
        swing = other_side(self._stance)
        elapsed = t - self._phase_start
        assert self._swing is not None and self._target is not None
        if cfg.step_adaptation and t < self._swing.t1 - 0.03:
            self._adapt_step(t, xi)
        force = forces.get(swing, 0.0)
        landed = force >= cfg.touchdown_force * self.weight and elapsed >= cfg.early_touchdown * (self._swing.t1 - self._phase_start)
        if landed and t < self._swing.t1 - 0.02:
            # An early contact counts only near the landing spot: a sole scraping the ground far
            # from it (a leaning robot) keeps swinging.
            sole = self._sole_world(swing).translation
            landed = math.hypot(sole[0] - self._target.position[0], sole[1] - self._target.position[1]) < cfg.touchdown_distance
        if landed:
            if t < self._swing.t1 - 1e-9:
                self.state.early_touchdowns += 1
            self._touch_down(t)
        elif t >= self._swing.t1 + cfg.late_touchdown:
            self.state.late_touchdowns += 1
            self._touch_down(t)
        elif not forces and t >= self._swing.t1:
            self._touch_down(t)

    def _begin_double(self, t: float, stance: str, duration: float) -> None:
        """Double support until ``t + duration``; then ``stance`` carries and the other foot swings."""
        self._phase, self._phase_start, self._phase_end = Phase.DOUBLE, t, t + duration
        self._stance = stance
        self._lift_off_issued = False
        self._reference = None

    def _begin_single(self, t: float) -> None:
        cfg = self.config
        self._phase, self._phase_start = Phase.SINGLE, t
        swing = other_side(self._stance)
        if cfg.drop_swing_contact:
            self.wbc.forget_contact(self.contacts[swing].name)
        stance_foot = self.feet[self._stance]
        if self._recovering:
            target, duration = self._predict_recovery(stance_foot, cfg.gait.single_support), cfg.gait.single_support
        else:
            # Plan from where the stance foot was *meant* to land: the step adapter's corrections do
            # not accumulate into a drift (re-anchored on the real foot when they are far apart).
            anchor = self._nominal_feet.get(self._stance)
            if anchor is None or np.linalg.norm(anchor.position - stance_foot.position) > cfg.anchor_tolerance:
                anchor = stance_foot
            target, duration = self.planner.next_step(anchor, self.command), cfg.gait.single_support
        target = self.planner.constrain(stance_foot, target)
        self._nominal_feet[swing] = target
        self._nominal_target = target
        self.state.planned_target = target.position
        target = self._apply_step_offset(stance_foot, target)
        self.state.target = target.position
        self._swing_nominal = duration
        duration = self._swing_duration(duration)
        self._phase_end = t + duration
        start = self._sole_world(swing)
        rotation = start.rotation
        start_pose = np.array([start.translation[0], start.translation[1], start.translation[2], math.atan2(rotation[1, 0], rotation[0, 0])])
        yaw = start_pose[3] + wrap_angle(target.yaw - start_pose[3])
        ground = self._sole_world(self._stance).translation[2]
        self._swing = SwingTrajectory(t, t + duration, start_pose, np.array([*target.position, ground - cfg.touchdown_depth, yaw]), apex=cfg.swing_apex)
        self._target = target
        self.state.nominal_target = self._nominal_target.position
        reference = self._plan_single(t, target, t + duration)
        self._nominal_offset = reference.dcm_at_segment_end(0) - target.position
        if self._recovering:
            self._nominal_offset = -side_sign(swing) * cfg.recovery_offset * np.array([-math.sin(target.yaw), math.cos(target.yaw)])
        self._reference = self._step_reference = reference
        self._dcm_shaper.reset()
        task = self.swing_tasks[swing]
        task.set_weight(cfg.recovery_swing_weight if self._recovering else cfg.swing_weight)
        self._swing_reference(t)
        self.wbc.add_task(task)

    def _recovery_swing_side(self, xi: np.ndarray) -> str:
        """Which foot steps when the capture point ``xi`` left the polygon: for each choice of
        stance foot, the CoP goes to the point of its sole nearest ``xi`` and the DCM runs on for
        the shortest swing (``ξ_T = p + (ξ − p) e^{ωT}``); the choice whose ``ξ_T`` stays closest
        to what it can still stand on — the stance sole, or the landing box of the other foot —
        wins. (The foot the capture point passed on the outside steps out when it is far past;
        when it is only just past, that foot carries and the other closes up.)"""
        cfg = self.config
        growth = math.exp(self.omega * (cfg.min_swing + cfg.contact_ramp))
        scores = {}
        for stance in self.contacts:
            swing = other_side(stance)
            sole = self.support_polygon((stance,))
            cop = clip_to_polygon(xi, sole)
            predicted = cop + (xi + self._disturbance_lead() - cop) * growth
            foot = self.feet[stance]
            local = foot.to_local(predicted)
            (x_lo, x_hi), (y_lo, y_hi) = self._landing_box(swing)
            reach = math.hypot(local[0] - min(max(local[0], x_lo), x_hi), local[1] - min(max(local[1], y_lo), y_hi))
            scores[swing] = min(reach, max(signed_distance(predicted, sole), 0.0))
        return min(scores, key=lambda side: (scores[side], side))

    def _landing_box(self, swing: str) -> tuple[tuple[float, float], tuple[float, float]]:
        cfg = self.config
        box = cfg.recovery_landing_box if self._recovering and cfg.recovery_landing_box is not None else cfg.landing_box
        (x_lo, x_hi), (y_lo, y_hi) = box
        return ((x_lo, x_hi), (y_lo, y_hi)) if side_sign(swing) > 0 else ((x_lo, x_hi), (-y_hi, -y_lo))

    def _adapt_step(self, t: float, xi: np.ndarray) -> None:
        cfg = self.config
        stance = self.feet[self._stance]
        swing = other_side(self._stance)
        assert self._swing is not None and self._nominal_target is not None
        elapsed = t - self._phase_start
        if self._duration_offset != 0.0 or self._phase_end != self._phase_start + self._swing_nominal:
            self._phase_end = self._phase_start + self._swing_duration(self._swing_nominal)
        remaining_range = (max(cfg.min_swing - elapsed, 0.02), max(cfg.max_swing - elapsed, 0.02))
        # (The adapter sees the measured DCM only: adding the disturbance lead here made
        # recoveries worse, 8/30 vs 15/30 at 150 N — the foot over-reached once the push ended.)
        task = self.swing_tasks[swing]
        if task.weight[0] < cfg.recovery_swing_weight and _distance(xi, self.state.dcm_ref) > cfg.stiff_swing_error:
            task.set_weight(cfg.recovery_swing_weight)  # pushed: the foot must get where the adapter sends it
        shaper = self._dcm_shaper
        dcm = shaper(t, xi, self._step_reference.evaluate(t)[0]) if shaper.active and self._step_reference is not None else xi
        # Recovering, the DCM controller holds the CoP on the stance sole's edge nearest the DCM
        # (clipped there), not at its centre: predicting from the centre overstated the DCM's run by
        # (edge - centre)(e^{ωT} - 1), up to ~0.1 m, and the foot landed that much too far outward
        # (feet 0.6-0.75 m apart, the pelvis rolled over; 100 N, tuning seeds 0-199: 199/200 vs
        # 185/200; 150 N, 0-99: 67 vs 68; adding the disturbance lead as well: 34/100 at 150 N).
        box = bounded_box(self._landing_box(swing), stance.to_local(self._nominal_target.position), cfg.max_adjustment)
        edge = self._recovering and cfg.recovery_cop != "centre"
        cop_hold = clip_to_polygon(dcm, self.support_polygon((self._stance,))) if edge else stance.position
        adjustment = self.adapter.adapt(  # type: ignore[union-attr]
            stance, cop_hold, dcm, self._nominal_target.position, self._phase_end - t, self._nominal_offset, box, remaining_range,
        )
        if edge and cfg.recovery_cop == "auto" and float(stance.to_local(adjustment.position)[0]) >= box[0][1] - 1e-6:
            adjustment = self.adapter.adapt(  # type: ignore[union-attr]
                stance, stance.position, dcm, self._nominal_target.position, self._phase_end - t, self._nominal_offset, box, remaining_range,
            )
        target = Footstep(swing, adjustment.position, self._nominal_target.yaw)
        self.state.planned_target = target.position
        target = self._apply_step_offset(stance, target)
        self.state.target = target.position
        touchdown = t + adjustment.remaining_time
        moved = _distance(target.position, self._target.position) > 2e-3 or abs(touchdown - self._swing.t1) > 4e-3  # type: ignore[union-attr]
        if moved:
            full = np.array([*target.position, self._swing.target[2], self._swing.target[3]])
            self._swing.retarget(t, full, touchdown)
            self._target = target
            planned = self._planned_for
            if planned is None or _distance(target.position, planned[0]) > cfg.replan_distance or abs(self._swing.t1 - planned[1]) > cfg.replan_time:
                self._reference = self._plan_single(t, target, self._swing.t1)

    def _touch_down(self, t: float) -> None:
        cfg = self.config
        swing = other_side(self._stance)
        self._remove_swing_task(self.swing_tasks[swing])
        self.wbc.add_contact(self.contacts[swing], ramp_time=cfg.contact_ramp)
        self.feet[swing] = self._measured_foot(swing)
        self._polygons = {}
        self.state.steps += 1
        self._swing = None
        if self._recovering:
            # Settle if the capture point is back inside both feet; otherwise the other foot steps.
            # (Measured on the tuning seeds at 150 N, no better: a shorter double support between
            # recovery steps, 26/40 vs 26/40; closing up a split wider than 0.45 m first, 22/40 vs 25/40.)
            if signed_distance(self.state.dcm, self.support_polygon()) > -cfg.settle_margin:
                # Feet alternate: the one just landed carries, the other closes up or steps on.
                self._begin_double(t, stance=swing, duration=max(cfg.gait.double_support, cfg.contact_ramp))
                self.state.recovery_steps += 1
            else:
                self._recovering = False
                self._settle(t)
            return
        if not self.walking and self._feet_together():
            self._settle(t)
            self._lead_after = t + cfg.lead_settle_time
            return
        # A large DCM error (a push) shortens the double support to the force ramp: the next
        # foot gets going at once.
        error = float(np.linalg.norm(self.state.dcm - self.state.dcm_ref))
        duration = cfg.gait.double_support if error < cfg.hurry_error else max(cfg.contact_ramp, 1e-3)
        self._begin_double(t, stance=swing, duration=duration)

    def _remove_swing_task(self, task: FramePoseTask) -> None:
        if any(existing is task for existing in self.wbc.tasks):
            self.wbc.remove_task(task.name)

    def _settle(self, t: float) -> None:
        self._phase, self._phase_start, self._phase_end = Phase.STAND, t, math.inf
        self._reference = None

    def _feet_together(self) -> bool:
        """The feet side by side at about the nominal width (a stop)."""
        left, right = self.feet["left"], self.feet["right"]
        local = right.to_local(left.position)
        return abs(local[0]) < 0.03 and abs(local[1] - self.config.gait.step_width) < 0.03

    # --- references ----------------------------------------------------------------------------------
    def _landings(self, first: Footstep) -> tuple[list[np.ndarray], np.ndarray | None]:
        """Landing spots after ``first`` (the preview) and the final CoP when the walk stops."""
        steps = [first]
        if self.walking:
            more, _ = self.planner.plan(first, self.command, self.config.preview_steps - 1)
            return [s.position for s in steps + more], None
        stance = self.feet[other_side(first.side)]
        if self._recovering:
            return [first.position], 0.5 * (first.position + stance.position)
        if self._feet_together_after(first, stance):
            return [first.position], 0.5 * (first.position + stance.position)
        closing = self.planner.next_step(first, VelocityCommand())
        return [first.position, closing.position], 0.5 * (first.position + closing.position)

    def _feet_together_after(self, a: Footstep, b: Footstep) -> bool:
        local = b.to_local(a.position)
        return abs(local[0]) < 0.03 and abs(abs(local[1]) - self.config.gait.step_width) < 0.03

    def _plan_single(self, t: float, target: Footstep, touchdown: float) -> DcmReference:
        self._planned_for = (target.position.copy(), touchdown)
        gait = self.config.gait
        stance = self.feet[self._stance].position
        landings, final = self._landings(target)
        segments = walking_cop_plan(CopSegment(max(touchdown - t, 1e-3), stance, stance), landings, gait.single_support, gait.double_support, final)
        return DcmReference(segments, self.omega, t)

    def _references(self, t: float, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(ξ_ref, ξ̇_ref, support polygon)`` for this tick; the swing task's reference."""
        gait = self.config.gait
        if self._phase is Phase.STAND:
            middle = 0.5 * (self.feet["left"].position + self.feet["right"].position)
            return middle, np.zeros(2), self.support_polygon()
        if self._phase is Phase.DOUBLE:
            if self._reference is None:
                stance = self.feet[self._stance]
                start = self.state.cop if self.state.steps or self._recovering else 0.5 * (self.feet["left"].position + self.feet["right"].position)
                duration = self._phase_end - t
                if self._recovering:
                    nominal = self._predict_recovery(stance, gait.single_support + self._phase_end - t)
                    landings, final = [nominal.position], 0.5 * (nominal.position + stance.position)
                elif self.walking or not self._feet_together():
                    first = self.planner.next_step(stance, self.command)
                    landings, final = self._landings(first)
                else:
                    landings, final = [], None
                duration = max(duration, 1e-3)
                hold = CopSegment(gait.single_support, stance.position, stance.position)
                rest = walking_cop_plan(hold, landings, gait.single_support, gait.double_support, final) if landings else []
                if rest:
                    # Start the CoP ramp where the reference starts at the measured DCM (within the feet).
                    after = DcmReference(rest, self.omega).initial[0]
                    start = clip_to_polygon(cop_start_for_dcm(xi, duration, after, stance.position, self.omega), self.support_polygon())
                segments = [CopSegment(duration, start, stance.position)] + rest
                self._reference = DcmReference(segments, self.omega, t)
            xi_ref, rate, _ = self._reference.evaluate(t)
            return xi_ref, rate, self.support_polygon()
        # Single support: the stance sole only; the swing sole follows its trajectory.
        assert self._swing is not None and self._reference is not None
        self._swing_reference(t)
        xi_ref, rate, _ = self._reference.evaluate(t)
        return xi_ref, rate, self.support_polygon((self._stance,))

    def _predict_recovery(self, stance: Footstep, horizon: float) -> Footstep:
        """Where a recovering foot goes: on the capture point ``horizon`` s ahead with the CoP on
        the stance sole, shifted outward by ``recovery_offset`` (the step adapter refines it)."""
        swing = other_side(stance.side)
        xi = self.state.dcm
        predicted = stance.position + (xi - stance.position) * math.exp(self.omega * horizon)
        outward = side_sign(swing) * self.config.recovery_offset * np.array([-math.sin(stance.yaw), math.cos(stance.yaw)])
        return Footstep(swing, predicted + outward, stance.yaw)

    def _swing_reference(self, t: float) -> None:
        swing = other_side(self._stance)
        assert self._swing is not None
        position, velocity, acceleration = self._swing.evaluate(t)
        if t > self._swing.t1:  # late: keep descending
            late = t - self._swing.t1
            position[2] -= self.config.descent_speed * late
            velocity[2] = -self.config.descent_speed
        yaw = float(position[3])
        c, s = math.cos(yaw), math.sin(yaw)
        rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        sole = pin.SE3(rotation, position[:3].copy())
        ankle = sole * self._sole_inverse[swing]
        # The ankle origin's velocity and acceleration (the sole turns about z only).
        ankle_xy, sole_xy = ankle.translation[:2].tolist(), position[:2].tolist()
        lx, ly = ankle_xy[0] - sole_xy[0], ankle_xy[1] - sole_xy[1]
        vx, vy, vz, wz = velocity.tolist()
        ax, ay, az_, az = acceleration.tolist()
        # ω × r and α × r + ω × (ω × r) for ω, α along z
        twist = np.array([vx - wz * ly, vy + wz * lx, vz, 0.0, 0.0, wz])
        accel = np.array([ax - az * ly - wz * wz * lx, ay + az * lx - wz * wz * ly, az_, 0.0, 0.0, az])
        self.swing_tasks[swing].set_reference(ankle, twist, accel)

    def _heading_reference(self) -> None:
        """Pelvis upright, heading the mean of the feet's (the swing target's while it flies)."""
        left, right = self.feet["left"].yaw, self.feet["right"].yaw
        if self._phase is Phase.SINGLE and self._target is not None:
            if self._target.side == "left":
                left = self._target.yaw
            else:
                right = self._target.yaw
        yaw = left + 0.5 * wrap_angle(right - left)
        if yaw == self._heading and not self._orientation_changed:
            return
        self._heading = yaw
        self._orientation_changed = False
        c, s = math.cos(yaw), math.sin(yaw)
        rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        if self._orientation_offset is not None:
            rotation = rotation @ pin.rpy.rpyToMatrix(self._orientation_offset)
        self.balance.base_task.set_reference(pin.SE3(rotation, np.zeros(3)))

    # --- residuals (a policy's corrections on top of the model-based walker) ----------------------
    # All zero (the default) leaves every computation of the walker untouched: bit for bit the
    # walker alone.
    def _clear_residuals(self) -> None:
        self._step_offset: np.ndarray | None = None  # stance-sole frame (x forward, y left), m
        self._duration_offset = 0.0  # s, added to the nominal single support
        self._swing_nominal = self.config.gait.single_support
        self._dcm_offset: np.ndarray | None = None  # world x, y, m
        self._height_offset = 0.0  # m
        self._orientation_offset: np.ndarray | None = None  # roll, pitch, yaw, rad
        self._orientation_changed = False

    def set_step_residual(self, offset: np.ndarray, duration: float = 0.0) -> None:
        """Shift where the swinging (or next) foot lands by ``offset`` (x, y in the stance sole's
        frame, m) on top of the plan and the step adapter's correction, and change the single
        support by ``duration`` s. The result stays inside the step adapter's landing box and
        ``[min_swing, max_swing]``; applied at once to a foot in flight (re-targeted swing)."""
        offset = np.asarray(offset, dtype=float).reshape(2)
        if not (np.all(np.isfinite(offset)) and math.isfinite(duration)):
            raise ValueError(f"step residual must be finite, got {offset}, {duration}")
        self._step_offset = offset.copy() if offset.any() else None
        self._duration_offset = float(duration)

    def set_reference_residual(self, dcm: np.ndarray | None = None, height: float = 0.0, orientation: np.ndarray | None = None) -> None:
        """Offsets on the references the walker gives the WBC: the DCM reference (world x, y, m;
        in steady state a CoM offset), the CoM height (m) and the pelvis orientation (roll, pitch,
        yaw about the walker's heading, rad)."""
        values = [np.zeros(2) if dcm is None else np.asarray(dcm, dtype=float).reshape(2),
                  np.zeros(3) if orientation is None else np.asarray(orientation, dtype=float).reshape(3)]
        if not (all(np.all(np.isfinite(x)) for x in values) and math.isfinite(height)):
            raise ValueError(f"reference residual must be finite, got {dcm}, {height}, {orientation}")
        self._dcm_offset = values[0].copy() if values[0].any() else None
        self._height_offset = float(height)
        orientation_offset = values[1].copy() if values[1].any() else None
        previous = self._orientation_offset
        same = (previous is None and orientation_offset is None) or (
            previous is not None and orientation_offset is not None and np.array_equal(previous, orientation_offset))
        if not same:
            self._orientation_changed = True
        self._orientation_offset = orientation_offset

    def _apply_step_offset(self, stance: Footstep, target: Footstep) -> Footstep:
        if self._step_offset is None:
            return target
        local = stance.to_local(target.position) + self._step_offset
        (x_lo, x_hi), (y_lo, y_hi) = self._landing_box(target.side)
        local = np.array([min(max(local[0], x_lo), x_hi), min(max(local[1], y_lo), y_hi)])
        return Footstep(target.side, stance.to_world(local), target.yaw)

    def _swing_duration(self, nominal: float) -> float:
        if self._duration_offset == 0.0:
            return nominal
        return min(max(nominal + self._duration_offset, self.config.min_swing), self.config.max_swing)

    # --- what a policy observes ----------------------------------------------------------------------
    @property
    def phase(self) -> Phase:
        return self._phase if self._anchored else Phase.STAND

    def phase_progress(self) -> float:
        """Fraction of the current double or single support elapsed at the last tick (0 standing)."""
        if not self._anchored or self._phase is Phase.STAND:
            return 0.0
        end = self._swing.t1 if self._phase is Phase.SINGLE and self._swing is not None else self._phase_end
        span = end - self._phase_start
        return min(max((self._time - self._phase_start) / span, 0.0), 1.0) if span > 0 else 1.0

    def phase_times(self) -> tuple[float, float, float]:
        """``(start, nominal end, planned end)`` of the current phase (s, the ticks' clock): in single
        support the touch-down the plan (with the step residual) set and the one the step adapter
        moved it to; in double support its end twice; standing ``(start, inf, inf)``."""
        if not self._anchored:
            return 0.0, math.inf, math.inf
        planned = self._swing.t1 if self._phase is Phase.SINGLE and self._swing is not None else self._phase_end
        return self._phase_start, self._phase_end, planned

    def next_footstep(self) -> Footstep:
        """Where the next foot lands: the swing target in single support, the plan's next step in
        double support, the first swing foot where it stands when standing."""
        if self._phase is Phase.SINGLE and self._target is not None:
            return self._target
        if self._phase is Phase.DOUBLE:
            return self.planner.next_step(self.feet[self._stance], self.command)
        return self.feet[self.planner.first_swing_side(self.command)]
