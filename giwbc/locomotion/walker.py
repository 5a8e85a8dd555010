"""Walking and push recovery by stepping, on the balance controller's whole-body QP.

Each WBC tick :meth:`WalkingController.update`:

1. measures the CoM, its velocity and the DCM ``ξ = c + ċ/ω`` (Pinocchio, from ``(q, v)``);
2. advances the **contact schedule** (:mod:`~giwbc.locomotion.contact_schedule`): double support →
   (the swing foot's contact ramped out with the WBC's force ramp) → single support → touch-down
   (the contact made again, its force ramped in) → double support … Touch-down is *early* when the
   foot's measured normal force exceeds a threshold after ``early_touchdown`` of the swing, *late*
   when it has not by the planned time (the foot keeps descending, for at most ``late_touchdown`` s);
3. in single support, the **step adapter** moves the landing spot and the touch-down time from
   the measured DCM, and the **swing trajectory** is re-targeted (continuous in flight;
   :mod:`~giwbc.locomotion.swing_control`);
4. sets the WBC references (:mod:`~giwbc.locomotion.walker_references`): the CoM task's horizontal
   acceleration from the **DCM controller** (``c̈ = ω² (c − p*)``, ``p*`` the CoP it asks for,
   clipped into the support polygon), its height held; the swing sole's SE3 pose task; the pelvis
   heading from the feet; the force regularisation's support point at ``p*``;
5. runs the WBC.

Standing, a push whose capture point leaves the support polygon (by ``push_margin``) starts
recovery steps — the foot on the side of the push steps to where the step adapter puts it —
until the capture point is back inside; then it settles in double support
(:mod:`~giwbc.locomotion.push_recovery`). A velocity command (:meth:`set_command`) walks; the
command going back to zero brings the feet together and stops. A policy may add residuals on top
(:mod:`~giwbc.locomotion.residuals`). The configuration and the per-tick state are in
:mod:`~giwbc.locomotion.walker_config` (re-exported here).

This module holds the controller itself — set-up, measurements, the tick, what a policy
observes; each of the modules above holds one part of its behaviour as a mixin class on the
controller's state.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import replace

import numpy as np
import pinocchio as pin

from giwbc.control.balance import BalanceController
from giwbc.control.contacts import Contact
from giwbc.control.tasks import FramePoseTask
from giwbc.control.wbc import WbcResult
from giwbc.locomotion.contact_schedule import ContactSchedule
from giwbc.locomotion.dcm import DcmController, DcmReference
from giwbc.locomotion.footsteps import Footstep, FootstepPlanner, VelocityCommand
from giwbc.locomotion.kernels import warm_up
from giwbc.locomotion.lipm import natural_frequency
from giwbc.locomotion.push_recovery import PushRecovery
from giwbc.locomotion.residuals import Residuals
from giwbc.locomotion.rolling_foot import YawSlipWatch, cop_on_raised_side, heading, lateral_rise
from giwbc.locomotion.step_adapter import DcmErrorShaper, StepAdapter
from giwbc.locomotion.support import convex_hull, sole_corners, sole_polygon
from giwbc.locomotion.swing import SwingTrajectory
from giwbc.locomotion.swing_control import SwingControl
from giwbc.locomotion.walker_config import TORSION_LOOSE, Phase, WalkerConfig, WalkerState
from giwbc.locomotion.walker_references import WalkerReferences
from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import Robot

__all__ = ["Phase", "WalkerConfig", "WalkerState", "WalkingController"]


class _FootForces(Mapping[str, float]):
    """The measured normal force per side (N), each read from the robot (``contact_wrench``) the
    first time it is asked for: the contact schedule reads the swinging foot's in single support
    only, once a touch-down can count (``early_touchdown`` of the swing), so a tick reads at most
    one of them (two reads a tick were ~5 % of a walking step; on an estimating robot each also
    computes the feet's poses). The robot does not change during a
    tick, so the values are those a read before it gives."""

    __slots__ = ("_robot", "_links", "_read")

    def __init__(self, robot: Robot, links: dict[str, str]) -> None:
        self._robot, self._links, self._read = robot, links, {}

    def _force(self, side: str) -> float | None:
        value = self._read.get(side)
        if value is None:
            link = self._links.get(side)
            if link is None:
                return None
            value = self._read[side] = float(self._robot.contact_wrench(link).force[2])
        return value

    def get(self, side: str, default: float | None = None) -> float | None:  # type: ignore[override]
        value = self._force(side)
        return default if value is None else value

    def __getitem__(self, side: str) -> float:
        value = self._force(side)
        if value is None:
            raise KeyError(side)
        return value

    def __iter__(self) -> Iterator[str]:
        return iter(self._links)

    def __len__(self) -> int:
        return len(self._links)


class WalkingController(ContactSchedule, PushRecovery, SwingControl, WalkerReferences, Residuals):
    """Walking / stepping on a :class:`BalanceController`'s WBC (see the module docstring)."""

    def __init__(self, description: RobotDescription, config: WalkerConfig | None = None, model: pin.Model | None = None) -> None:
        self.config = config = config or WalkerConfig()
        self.description = description
        torsion = TORSION_LOOSE if config.torsion is None and config.recovery_torsion is not None else config.torsion
        overrides = (("mu", config.friction), ("torsion", torsion), ("limb_yaw_momentum_weight", config.yaw_momentum_weight),
                     ("contact_kd", config.contact_kd))
        floor = {name: value for name, value in overrides if value is not None}
        balance = replace(config.balance, **floor) if floor else config.balance
        self.balance = BalanceController(description, balance, model)
        self.wbc = self.balance.wbc
        self.wbc.relax_joint_limits = self.wbc.relax_joint_limits or config.relax_joint_limits
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
        warm_up()  # the tick's compiled kernels, loaded or compiled now rather than at a first tick
        self.weight = description.total_mass * 9.81
        # ``config`` is the one walking now: ``base_config`` (the constructor's) but for a command
        # beyond its base gait's limits, its ``for_command`` (faster cadence, longer steps).
        self.base_config = config
        self.planner = self._base_planner = FootstepPlanner(config.gait)
        self.command = VelocityCommand()
        self._in_place = False
        self.state = WalkerState()
        self._com_height: float | None = None
        self.omega = 0.0
        self.adapter: StepAdapter | None = None
        self.dcm_controller: DcmController | None = None
        self._anchored = False
        self.last_result: WbcResult | None = None  # the last tick's
        self._force_links = {side: contact.link for side, contact in self.contacts.items()}  # (for step()'s _FootForces)
        self._swing_rotation = np.eye(3)  # the swing sole's rotation, rewritten at every tick of a swing (swing_control)
        # A floor not holding the yaw moment (WalkerConfig.yaw_slip_weight): the limbs' yaw momentum task's weight raised.
        scheduled = config.yaw_slip_weight is not None and self.balance.limb_yaw_task is not None
        self._yaw_slip = YawSlipWatch(math.radians(config.yaw_slip_angle), config.yaw_slip_hold) if scheduled else None
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
        notes say how (also kept in ``state.notes``). Beyond the base gait's limits the walker
        switches to the gait that walks it (:meth:`WalkerConfig.for_command`: faster cadence,
        longer steps), from the next step on; inside them, the base gait."""
        clamped = self._base_planner.clamp(VelocityCommand(vx, vy, yaw_rate))
        if clamped.command != self.command:  # (the closed-loop heading and velocity restart)
            self._yaw_goal = None
            self._touchdowns = []
            self.config = self.base_config.for_command(clamped.command)
            self.planner = self._base_planner if self.config is self.base_config else FootstepPlanner(self.config.gait)
            self._base_planner.correction = self._base_planner.offset = (0.0, 0.0)
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
        self.config, self.planner = self.base_config, self._base_planner
        self._base_planner.correction = self._base_planner.offset = (0.0, 0.0)
        self.balance.reset(q)
        for task in self.swing_tasks.values():
            self._remove_swing_task(task)
        self._polygons: dict[tuple, np.ndarray] = {}
        if self._yaw_slip is not None:
            self._yaw_slip.reset()
        self._heading = math.nan
        self._hip_roll = 0.0
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
        self._step_frames: tuple | None = None  # (key, StepFrame, landing box) of the step in flight
        self._dcm_shaper = DcmErrorShaper(self.config.adapt_deadband, self.config.adapt_filter, self.config.adapt_full_error, self.config.adapt_fade_delay)
        self._lateral_shaper = DcmErrorShaper(self.config.adapt_lateral_deadband or 0.0, self.config.adapt_filter)  # (adapt_lateral_deadband)
        self._recovering = False
        self._crouch = 0.0
        self._swap_at = math.nan  # when a push last swapped the feet's roles in double support (push_recovery)
        self._quick_land: tuple[float, float] | None = None  # (lift-off, touch-down) of a quick landing (push_recovery)
        self._lead_after: float | None = None  # set at the first tick: start_settle_time after it
        self._xi_previous: np.ndarray | None = None
        self._xi_rate: np.ndarray | None = None
        self._last_cop: np.ndarray | None = None
        self._last_tick = 0.0
        self._nominal_feet: dict[str, Footstep] = {}
        self._yaw_goal: tuple[float, float] | None = None  # (time, heading) the envelope's turning counts from
        self._touchdowns: list[tuple[float, np.ndarray, float, np.ndarray]] = []  # (time, feet's middle, heading, CoM xy), while walking
        self._planned_for: tuple[np.ndarray, float] | None = None
        self._reference: DcmReference | None = None
        self._time = 0.0
        self._anchored = True
        self._clear_residuals()

    # --- measurements ------------------------------------------------------------------------------
    def _measure(self, q: np.ndarray, v: np.ndarray) -> None:
        data = self._data
        self._com = pin.centerOfMass(self.model, data, q, v, False)  # (a new array: data.com[0]'s values)
        self._com_velocity = np.array(data.vcom[0])

    def _sole_world(self, side: str) -> pin.SE3:
        contact = self.contacts[side]
        return self._data.oMi[contact.joint_id] * contact.placement

    def _measured_foot(self, side: str) -> Footstep:
        placement = self._sole_world(side)
        rotation = placement.rotation
        return Footstep(side, placement.translation[:2].copy(), math.atan2(rotation[1, 0], rotation[0, 0]))

    def contact_plans(self, links: Sequence[str]) -> dict[str, np.ndarray]:
        """Per stance side, which of ``links`` (an estimator's contact order) carry in that side's
        single support: the plan an estimating robot takes while a foot swings (its quasi-static
        force estimate can read tens of N, and a swinging foot is never a still stance foot)."""
        return {side: np.array([link == contact.link for link in links]) for side, contact in self.contacts.items()}

    def single_support_plan(self, plans: dict[str, np.ndarray]) -> np.ndarray | None:
        """``plans[stance]`` (from :meth:`contact_plans`) in single support, else None (the
        estimator detects contacts from forces: a landing foot counts once loaded)."""
        return plans[self.state.stance] if self._phase is Phase.SINGLE else None

    def support_polygon(self, sides: tuple[str, ...] | None = None) -> np.ndarray:
        """CCW hull of the soles in contact (both in double support) at their planned holds: each
        sole's support polygon as its contact has it now (the description's sole with the WBC's
        margin; the edge or corner a rolled foot stands on)."""
        sides = tuple(self.contacts) if sides is None else sides
        key = (sides, tuple((self.contacts[side].support_mode, self.contacts[side].friction_version) for side in sides))
        cached = self._polygons.get(key)
        if cached is not None:
            return cached
        corners = []
        for side in sides:
            contact = self.contacts[side]
            foot = self.feet[side]
            polygon = contact.support_polygon()
            if polygon is None:
                corners.append(sole_corners(foot.position, foot.yaw, contact.half_length, contact.half_width))  # type: ignore[attr-defined]
            else:
                corners.append(sole_polygon(foot.position, foot.yaw, polygon))
        hull = self._polygons[key] = convex_hull(np.vstack(corners))
        return hull

    # --- the tick ----------------------------------------------------------------------------------
    def update(self, q: np.ndarray, v: np.ndarray, t: float, foot_forces: Mapping[str, float] | None = None) -> WbcResult:
        """One tick at time ``t`` for the Pinocchio state ``(q, v)``; ``foot_forces`` are the
        measured normal forces (N) per side (``None``: switch on the schedule alone).

        A non-finite state plans nothing (the schedule and the references wait) and returns the
        WBC's fallback command (``WbcStatus.INVALID_STATE``, with its message, counted in
        ``wbc.failures``); it never raises. Wrong shapes raise ``ValueError``."""
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        # (A finite sum of squares: every entry finite, one BLAS call; otherwise the sum decides.)
        if not math.isfinite(q.dot(q) + v.dot(v)) and not math.isfinite(float(q.sum() + v.sum())):
            self.last_result = self.wbc.update(q, v, t)
            return self.last_result
        if not self._anchored:
            self.reset(q)
        self._time = t = float(t)
        if self._lead_after is None:
            self._lead_after = t + self.config.start_settle_time
        self._measure(q, v)
        omega = self.omega
        cx, cy, _ = self._com.tolist()
        vx, vy, _ = self._com_velocity.tolist()
        xi = np.array([cx + vx / omega, cy + vy / omega])
        self._estimate_disturbance(t, xi)
        self.state.dcm = xi
        self._advance(t, xi, foot_forces or {})
        xi_ref, xi_rate_ref, support = self._references(t, xi)
        if self._dcm_offset is not None:
            xi_ref = xi_ref + self._dcm_offset
        controller = self.dcm_controller
        controller.gain = self.config.standing_dcm_gain if self._phase is Phase.STAND else self.config.dcm_gain
        cop = controller.desired_cop(xi, xi_ref, xi_rate_ref, support)
        if self.config.roll_cop_tilt > 0.0 and self._phase is Phase.SINGLE:  # a stance foot rolling on its rim
            foot = self.feet[self._stance]
            cop, moved = cop_on_raised_side(cop, foot.position, foot.yaw, lateral_rise(self._sole_world(self._stance).rotation),
                                            math.radians(self.config.roll_cop_tilt), self.config.roll_cop_margin)
            self.state.rolled_ticks += moved
        self._last_cop = cop
        acceleration = controller.com_acceleration(self._com, cop)
        # The CoM task's horizontal rows have no damping (set in reset): their position error
        # carries the acceleration, ẍ* = kp (c + c̈/kp − c) = c̈ — one reference, no rates to gather.
        kp = self._com_kp
        ax, ay = acceleration.tolist()
        self.balance.com_task.set_reference(np.array([cx + ax / kp, cy + ay / kp, self._ground + self._com_height + self._height_offset - self._recovery_drop()]))
        if self._phase is not Phase.SINGLE:  # (one foot: it carries the weight, no split to set)
            self.balance.force_regularization.set_support_point(np.array([cop[0], cop[1], 0.0]))
        self._heading_reference(self._hip_roll_reference(xi, xi_ref))
        self.state.dcm_ref, self.state.cop = xi_ref, cop
        self.state.com, self.state.com_velocity = self._com, self._com_velocity
        self.state.phase, self.state.stance = self._phase, self._stance
        spring = self.config.walking_limit_spring
        if spring is not None:
            # not walking: BalanceConfig.limit_spring (what the WBC was built with)
            self.wbc.limit_spring = spring if self.walking and not self._recovering else self.balance.config.limit_spring
        if self._yaw_slip is not None:
            self._schedule_yaw_momentum(t)
        if self.config.recovery_torsion is not None:
            self._schedule_torsion()
        self.last_result = self.wbc.update(q, v, t)
        return self.last_result

    def _schedule_yaw_momentum(self, t: float) -> None:
        """The limbs' yaw momentum task at ``yaw_slip_weight`` while a stance foot lately turned on the floor,
        at ``yaw_recovery_weight`` (if set) while recovering from a push, else at its own weight."""
        cfg = self.config
        single = self._phase is Phase.SINGLE
        yaw = heading(self._sole_world(self._stance).rotation) if single else None
        slipping = self._yaw_slip.update(t, (self._stance, self._phase_start) if single else None, yaw)  # type: ignore[union-attr]
        task = self.balance.limb_yaw_task
        if slipping:
            weight = cfg.yaw_slip_weight
        elif self._recovering and cfg.yaw_recovery_weight is not None:
            weight = cfg.yaw_recovery_weight
        else:
            weight = self.balance.config.limb_yaw_momentum_weight
        if task.weight[0] != weight:  # type: ignore[union-attr]
            task.set_weight(weight)

    def _schedule_torsion(self) -> None:
        """Every foot's yaw moment bound at ``recovery_torsion`` while recovering from a push, else at
        the walker's own torsion: a recovery step's stance foot is the one a soft floor turns."""
        torsion = self.config.recovery_torsion if self._recovering else self.balance.config.torsion
        for contact in self.contacts.values():
            contact.set_torsion(torsion)  # type: ignore[attr-defined]

    def step(self, robot: Robot) -> WbcResult:
        """Read ``robot`` (state, foot forces), run one tick, command its joint torques. The foot
        forces are read when the schedule asks for them (:class:`_FootForces`: the swinging foot's late
        in a swing, none otherwise), the same values as read beforehand."""
        q, v = robot.generalized_state()
        result = self.update(q, v, robot.time(), _FootForces(robot, self._force_links))
        robot.set_joint_torques(result.tau)
        return result

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
