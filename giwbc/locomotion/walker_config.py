"""What the walking controller is configured with and what it reports: its contact-schedule
:class:`Phase`, its :class:`WalkerConfig` (gait, gains, switching and push-recovery thresholds)
and the :class:`WalkerState` it leaves after each tick (for logs, tests and benchmarks).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

import numpy as np

from giwbc.control.balance import BalanceConfig
from giwbc.locomotion.footsteps import GaitConfig, VelocityCommand
from giwbc.locomotion.residuals import check_error_gate
from giwbc.locomotion.step_adapter import StepAdapterWeights


class Phase(enum.Enum):
    STAND = "stand"  # double support, no step planned
    DOUBLE = "double"  # double support between steps
    SINGLE = "single"  # one foot swinging


@dataclass(frozen=True)
class WalkerConfig:
    """Gait, gains and switching thresholds of :class:`~giwbc.locomotion.walker.WalkingController`."""

    gait: GaitConfig = field(default_factory=GaitConfig)
    # proxsuite gets 20 outer iterations (default 10): the ticks of a contact switch need more.
    balance: BalanceConfig = field(default_factory=lambda: BalanceConfig(min_normal_force=5.0, solver_settings={"max_iter": 20}))
    # The friction coefficient the WBC plans every foot force with (None: ``balance.mu``, 0.8); a floor
    # not known to grip that well: the "any_floor" preset (ANY_FLOOR_OPTIONS).
    friction: float | None = None
    # m: the feet's yaw moment kept within torsion x normal force (None: ``balance.torsion``, i.e. what
    # the sole's friction allows); a compliant floor turns a loaded foot under far less (BalanceConfig).
    torsion: float | None = None
    # The limbs' yaw momentum task's weight (None: ``balance.limb_yaw_momentum_weight``, off): a swinging
    # leg's yaw momentum taken by the trunk and arms, not by a yaw moment on the stance foot
    # (giwbc.control.yaw_momentum; any_floor: a compliant floor turns a loaded foot under that moment).
    yaw_momentum_weight: float | None = None
    # The task's weight when the floor does not hold yaw (None: off, yaw_momentum_weight throughout): once
    # a stance sole turned more than ``yaw_slip_angle`` deg within one single support, for ``yaw_slip_hold``
    # s (giwbc.locomotion.rolling_foot.YawSlipWatch). While recovering from a push (and no slip seen),
    # ``yaw_recovery_weight`` (None: unchanged): a recovery step's stance foot carries the largest yaw
    # moments. Elsewhere the lower weight, which the walker on an estimated state needs. Without the task
    # (yaw_momentum_weight 0) nothing is scheduled.
    yaw_slip_weight: float | None = None
    yaw_slip_angle: float = 10.0
    yaw_slip_hold: float = 10.0
    yaw_recovery_weight: float | None = None
    # m: while recovering from a push, every foot's yaw moment kept within recovery_torsion x normal force
    # (None: off). A recovery step's stance foot carries the largest yaw moments and a compliant floor turns
    # it under them (soft floor: a loaded sole turned 20-60 deg and rolled over); walking keeps ``torsion``
    # (the yaw moment is what holds the heading while a leg swings: a global bound costs tracking). With
    # ``torsion`` None the feet are built with TORSION_LOOSE (never binding) so that the rows exist.
    recovery_torsion: float | None = None
    # 1/s: the damping on the contact motion rows (None: ``balance.contact_kd``, 20): the WBC asks each
    # loaded foot's twist J v to decay at this rate, a hard constraint. On an estimated state J v carries
    # the estimate's base rate (a few ms late, or led: EstimatorConfig.omega_lead) times the leg's length,
    # and a point or rim foot really turns: the damping then feeds a late rate back at high gain.
    contact_kd: float | None = None
    com_height: float | None = None  # m above the soles; default: the standing pose's
    dcm_gain: float = 5.0  # s⁻¹, walking
    standing_dcm_gain: float = 8.0  # s⁻¹, standing (stiffer: feet-in-place balance)
    com_height_kp: float = 100.0
    swing_apex: float = 0.07  # m
    swing_weight: float = 2.0  # walking: low, the CoM task keeps the priority
    # The WBC's joint-limit spring (zone rad, kp N m/rad, kd N m s/rad: WholeBodyController.set_limit_spring)
    # while the walker walks (not standing, not recovering from a push: there the ankles need their full
    # range; BalanceConfig.limit_spring holds then). A foot rolling on a rim turns with its ankle roll,
    # which only a torque at that joint turns back; on the nominal plant the walk is bit for bit the
    # same (no joint enters the zone). None: off, the default: with the friction and swing gain above,
    # (0.05, 600, 10) did not help on the truth (tuning seeds 20001-20002, 0.3 / 0.5 / -0.3 m/s and
    # turning, 12 s, 5 variants: 3 falls of 40 with it, 1 without) nor on the estimate (G1Walk, 0.3 m/s,
    # seeds 20000-20002, capsule / point / all_at_once / frictional feet: 6 of 12 ends either way).
    # (README, "Why the feet rock, and a joint-limit spring".)
    walking_limit_spring: tuple[float, float, float] | None = None
    recovery_swing_weight: float = 10.0  # recovering from a push: the foot must get there
    # deg (0: off): in single support, a stance sole tilted more than this across it (rolled onto a rim:
    # giwbc.locomotion.rolling_foot) has the CoP the walker asks held ``roll_cop_margin`` m on its raised
    # side of the centre line, where the foot still pushes (the ankle brings it back flat).
    roll_cop_tilt: float = 0.0
    roll_cop_margin: float = 0.0
    # The WBC solves a tick again without its joint-limit bounds when they leave its QP without a
    # solution (WholeBodyController.relax_joint_limits: a foot rolling on a rim or a point turns its
    # ankle faster than the bounds allow) instead of falling back to decaying torques.
    relax_joint_limits: bool = False
    swing_kp: float = 400.0
    contact_ramp: float = 0.04  # s, force ramp at lift-off and touch-down
    start_shift: float = 0.3  # s, double support before the first step (weight shift)
    preview_steps: int = 3
    touchdown_force: float = 0.15  # fraction of the weight on the swing foot meaning "landed"
    early_touchdown: float = 0.6  # fraction of the swing after which contact means touch-down
    touchdown_distance: float = 0.05  # m: an early contact this close to the landing spot is a touch-down
    late_touchdown: float = 0.08  # s, how long past the plan the foot may keep descending
    # Fraction of the weight meaning "landed" from the planned touch-down on (None: touchdown_force).
    # Deployed, sole forces come from the legs' efforts: a foot that has met the ground under the swing
    # task carries little until the contact takes the weight, so at 0.35 of the weight the touch-down
    # waited for the late-touchdown search, whose foot, pressed on down, rolled onto its sole edge
    # (the walker alone on the estimate of ideal sensors: 55 % of walking-protocol episodes at 0 N,
    # ended on an ankle roll's soft limit; 100 % with 0.1, selection seeds 500-599). In the
    # deployment preset: 0.1 (0.2 left the AHRS estimate's figures where the preset's 0.35 had them).
    late_touchdown_force: float | None = None
    late_touchdown_height: float = 0.02  # m: ... on a sole at most this far above the stance sole
    descent_speed: float = 0.25  # m/s, of a late foot
    touchdown_depth: float = 0.003  # m, the swing aims this far below the ground
    step_adaptation: bool = True
    # On an *estimated* DCM (deployment): the adapter sees the step's own nominal DCM reference
    # plus the error beyond ``adapt_deadband`` (m), low-passed over ``adapt_filter`` (s), and moves
    # a landing at most ``max_adjustment`` (m, each axis of the stance frame) from the plan:
    # estimation noise leaves the nominal steps alone, a push still moves them.
    adapt_deadband: float = 0.0
    adapt_filter: float = 0.0
    # m (> adapt_deadband, inf: off): a (low-passed) DCM error this large reaches the adapter whole, the
    # deadband fading out linearly below it (giwbc.locomotion.step_adapter.DcmErrorShaper).
    adapt_full_error: float = math.inf
    # s (0: at once): with adapt_full_error, the fading's extra comes in over this long an error beyond
    # the deadband (a push's error lasts, the estimate's swing-end excursion does not).
    adapt_fade_delay: float = 0.0
    # m (None: off, the lateral error goes through adapt_deadband with the rest): the DCM error's part
    # across the stance foot's heading reaches the adapter through its own deadband (low-passed over
    # adapt_filter), the forward part through adapt_deadband. A point or rim foot gives the ankle almost
    # no lateral CoP: a lateral DCM error inside the common 3 cm deadband then stays (the DCM controller's
    # CoP saturates on the sole's edge, the foot rolls onto it) and grows over steps until a stance ankle
    # roll passes its limit; a step placed by it instead re-centres the DCM. Only where the adapter's DCM
    # is shaped at all (adapt_deadband or adapt_filter > 0: an estimated DCM); else the measured DCM whole.
    adapt_lateral_deadband: float | None = None
    # s (0: off): in the last this-many seconds before the planned touch-down the landing spot and time
    # are held — a change then is barely reachable by the foot and, on an estimated DCM, is mostly the
    # estimate's own swing-end error (the stance foot rolls).
    adapt_freeze_time: float = 0.0
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
    # s after the walker's first tick: the capture point alone decides, as after a stop. Deployed, the
    # estimate restarts from its calibration just before the walker's first tick, and that restart
    # plus the controller taking over from the joint hold read as a push: with the AHRS IMU emulated
    # (giwbc deploy --imu-profile ahrs) the disturbance lead was -1.4 m/s on the first tick and the
    # standing G1 started a recovery step it did not need, which stopped it on an ankle roll's soft limit.
    start_settle_time: float = 0.0
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
    # A hip strategy (0: off): the pelvis rolls *into* a lateral DCM error, by ``hip_roll_gain`` rad
    # per m of the error across the heading (at most ``hip_roll_max`` rad), in proportion to
    # clip((|ξ − ξ_ref| − start) / (full − start), 0, 1) with ``hip_gate = (start, full)`` m: nothing
    # while the walker tracks its DCM, in full after a push. Leaning the trunk toward the fall gives
    # the ground a shear force back under the CoM, where the stance foot's CoP is at its edge and the
    # other foot cannot cross (the G1's lateral pushes end on a stance ankle roll's soft limit).
    # Walker alone on the estimate, 50 N x 0.2 s while walking (giwbc evaluate --protocol walk):
    # see policies/README.md ("a hand-made hip strategy").
    hip_roll_gain: float = 0.0
    hip_roll_max: float = 0.2
    hip_gate: tuple[float, float] = (0.03, 0.08)
    # Pushes while walking or stepping in place (issue 38: 30 N s at any gait phase).
    # A DCM (plus the disturbance lead) this far (m; inf: off) from its reference hands the steps to
    # the standing recovery's — its choice of foot (in double support the foot on the push's side
    # steps now; in a swing the swinging foot comes down on the adapter's spot and the other steps
    # on), its landing box and stiff swing, the CoP on the stance sole's edge — with only the force
    # ramp between the steps, until the capture point is back inside the feet; then the walk goes on
    # from a stand. Unpushed, the error with the lead stays under 0.11 m (0.5 m/s and in place).
    # Tuning seed 700 of the gait-phase protocol (30 N s, 8 directions x 5 phases): in place 20/40,
    # walking 0.5 m/s 19/40, against 16/40 and 14/40 before; with push_reach_speed 3.0 as well 21/40
    # and 16/40, with 1.5 m/s 17/40 and 11/40 (short quick steps: a lateral push then needs the other
    # foot's inward step before the next outward one).
    walking_recovery_error: float = 0.15
    # In double support while walking, below walking_recovery_error: when the DCM plus the disturbance
    # lead is more than ``push_swap_error`` m (inf: off) from its reference and the foot that was to
    # carry would leave the capture point ``push_swap_margin`` m farther out of reach than the other,
    # the feet swap roles: the foot on the side of the push steps now.
    push_swap_error: float = 0.15
    push_swap_margin: float = 0.02
    # Pushed while walking (the DCM more than stiff_swing_error from its reference, or a walking
    # recovery), the step adapter may keep the landing where the swinging foot reaches in the time it
    # picks (``push_reach_speed`` m/s over the remaining swing plus ``push_reach_slack`` m, each
    # stance-frame axis; 0: off), landing as soon as ``push_min_swing`` s after lift-off.
    push_reach_speed: float = 0.0
    push_reach_slack: float = 0.05
    push_min_swing: float = 0.15
    # A walking recovery while a foot swings and the DCM (plus the disturbance lead) is more than
    # ``quick_land_margin`` m (inf: off) outward of the stance sole's centre line, across it: the
    # swinging foot cannot catch it (it would cross the stance leg), so it lands at once, beside the
    # stance foot at the landing box's narrowest width, within ``quick_land_reach`` m of where it is
    # (the DCM's own progress along the stance foot), ``quick_land_time`` s from now at the earliest
    # and no sooner than ``push_min_swing`` after lift-off; the stance foot then steps out after the
    # force ramp (the recovery's next step, its reach from the DCM): two steps, no crossing. The
    # closer the quick landing to the stance foot (``quick_land_width``, m between the soles' centres,
    # at most the box's narrowest), the nearer its CoP to the DCM and the shorter the split the next
    # step needs. Gait-phase protocol (30 N s, 8 directions x 5 phases), tuning seeds 700-702, stepping
    # in place / walking 0.5 m/s: off 58 / 58 of 120; 0.08 m and 0.12 m 70 / 60; on seed 700 alone
    # (off 20 / 19 of 40): margin 0.0 at the box's 0.17 m 15 / 17, 0.08 at 0.17 m 22 / 21, 0.04 at
    # 0.12 m 24 / 19. Unpushed walking never recovers, so never lands quickly: bit for bit the same.
    # (Tried and dropped: in double support, the foot on the side of the DCM error's lateral part
    # stepping first — 3 / 2 of 40, a backward push read as lateral stepped a foot out sideways and
    # the DCM followed it; a recovery box 0.9 m wide, 12 / 18; 0.6 m long, walking 20 of 40.)
    quick_land_margin: float = 0.08
    quick_land_time: float = 0.08
    quick_land_reach: float = 0.15
    quick_land_width: float = 0.12
    # Walking, a recovery whose capture point is back inside the feet at a touch-down: the walk goes on
    # with the foot just landed carrying and the other stepping after this long a double support (s;
    # inf: off, a stand first, then the walk's start_shift). Off: on seed 700, 0.1 s gave 21 / 20 of 40
    # alone and 25 / 20 with the quick landing (24 / 21 without): a wide split sank during the stand,
    # and as much during the step that was to close it (the stance hip at its torque limit).
    recovery_walk_on: float = math.inf
    # Walking, a push late in a swing (issue 38): the walking-push check (walking_recovery_error) runs to the
    # touch-down, the last 0.03 s of the swing and the late-touchdown wait included, and a swing a walking
    # recovery caught past its planned touch-down lands as a quick landing does (its sole down at the stance
    # sole's height, loaded or not; so does any walking recovery's swing past its planned touch-down). Off (the former behaviour), a push in the last 0.03 s of a swing was
    # seen only at the touch-down, after up to late_touchdown (0.08 s) of waiting: stepping in place, pushed
    # back at phase 0.4, the robot tipped back over its heels with the swinging foot hovering until the
    # recovery began with the DCM 0.3 m behind (tuning seed 700). Gait-phase protocol (30 N s, 8 directions x
    # 5 phases), tuning seeds 700-702, walking 0.5 m/s / stepping in place: off 60 / 74 of 120, on 79 / 90.
    # Unpushed (the DCM error with the lead under walking_recovery_error) nothing changes, bit for bit;
    # standing recoveries are not walking: untouched. Off by default: a G1Walk-v0 env under a constant step
    # residual (5 cm forward, 3.2 cm right, 0.2 m/s, seed 1) caught 6 of its first 7 steps as walking pushes
    # with it on and ended at agent step 160, where it walks with it off (tests/test_env_walk.py); the shipped
    # policy was trained without it. Opt in for the model-based walker alone.
    late_swing_push: bool = False
    # m (inf: off): a recovering foot lands at most this far from the stance sole's centre, drawn toward it (the
    # box's narrowest width kept; the touch-down time the adapter's). The recovery box's corners (0.5 m on,
    # 0.75 m across: 0.9 m) are beyond a G1 leg: a diagonal push's foot landed there, the pelvis rolled, the
    # split sank and the robot fell; a nearer landing lets the DCM run on past it, and the other foot steps
    # next. Standing impulse grid (8 directions, 30 / 35 N s), tuning seeds 700-702 and 20000-20005 (72 per
    # impulse): off 61 / 49, 0.75 m 68 / 66, 0.72 m 72 / 50 (pure lateral pushes need the box's full 0.75 m),
    # 0.8 m (20000-20005 only) 31 / 46 of 48. Gait-phase protocol, seed 700 (in place / walking of 40):
    # off 24 / 21, 0.75 m 25 / 22. Tried and dropped for the grid (seeds 700-702; or as said): the pelvis
    # orientation task's weight while recovering 3 (roll, pitch, yaw) 22 / 18 of 24 against 20 / 16, but on
    # 20000-20005 38 / 24 against 41 / 33 of 48 (forward pushes failed); 3 on roll and pitch only 23 / 18; 0.3,
    # 9 / 8; a recovery step's nominal swing 0.28 s (the adapter held the DCM to land on the box's edge late)
    # 18 / 14, the same but not for backward steps 18 / 18; recovery_offset 0 / 0.08 / 0.11 m 12 / 8, 17 / 15,
    # 15 / 12; a recovery box 0.65 m across 21 / 11. The price: at 25 N s the forward diagonals the adapter
    # had landed 0.75-0.85 m out, settling on a wide split, now fall more often (tuning seeds, 72 each at
    # 25 / 30 / 35 N s): off 70 / 61 / 49, 0.75 m 61 / 68 / 66, 0.78 m 57 / 51 / 60; limited only once the
    # adapter asks for more than 0.85 (0.82) m in a swing, latched: 70 / 55 / 64 (60 / 67 / 65); the forward part kept,
    # only the lateral part shortened: 66 / 51 / 48 (the forward reach is what the limit takes off).
    recovery_max_split: float = 0.75

    def __post_init__(self) -> None:
        if self.preview_steps < 1:
            raise ValueError("preview_steps must be >= 1")
        if self.friction is not None and not (math.isfinite(self.friction) and self.friction > 0.0):
            raise ValueError(f"friction must be None or a finite coefficient > 0, got {self.friction!r}")
        if self.torsion is not None and not (math.isfinite(self.torsion) and self.torsion > 0.0):
            raise ValueError(f"torsion must be None or a finite lever arm > 0 m, got {self.torsion!r}")
        if self.contact_kd is not None and not (math.isfinite(self.contact_kd) and self.contact_kd >= 0.0):
            raise ValueError(f"contact_kd must be None or a finite damping >= 0 (1/s), got {self.contact_kd!r}")
        if self.yaw_momentum_weight is not None and not (math.isfinite(self.yaw_momentum_weight) and self.yaw_momentum_weight >= 0.0):
            raise ValueError(f"yaw_momentum_weight must be None or a finite weight >= 0, got {self.yaw_momentum_weight!r}")
        if self.yaw_slip_weight is not None:
            if not (math.isfinite(self.yaw_slip_weight) and self.yaw_slip_weight >= 0.0):
                raise ValueError(f"yaw_slip_weight must be None or a finite weight >= 0, got {self.yaw_slip_weight!r}")
            if not (math.isfinite(self.yaw_slip_angle) and 0.0 < self.yaw_slip_angle < 180.0):
                raise ValueError(f"yaw_slip_angle must be in (0, 180) deg, got {self.yaw_slip_angle!r}")
            if not (math.isfinite(self.yaw_slip_hold) and self.yaw_slip_hold >= 0.0):
                raise ValueError(f"yaw_slip_hold must be a finite time >= 0 s, got {self.yaw_slip_hold!r}")
        if self.recovery_torsion is not None and not (math.isfinite(self.recovery_torsion) and self.recovery_torsion > 0.0):
            raise ValueError(f"recovery_torsion must be None or a finite lever arm > 0 m, got {self.recovery_torsion!r}")
        if self.yaw_recovery_weight is not None and not (math.isfinite(self.yaw_recovery_weight) and self.yaw_recovery_weight >= 0.0):
            raise ValueError(f"yaw_recovery_weight must be None or a finite weight >= 0, got {self.yaw_recovery_weight!r}")
        spring = self.walking_limit_spring
        if spring is not None and not (len(spring) == 3 and all(math.isfinite(float(x)) for x in spring) and spring[0] > 0 and min(spring[1:]) >= 0):
            raise ValueError(f"walking_limit_spring must be None or (zone > 0 rad, kp >= 0 N m/rad, kd >= 0 N m s/rad), got {spring!r}")
        if not (0.0 < self.min_swing <= self.gait.single_support <= self.max_swing):
            raise ValueError("need 0 < min_swing <= single_support <= max_swing")
        if self.contact_ramp < 0 or self.contact_ramp >= self.gait.double_support + 1e-12 and self.contact_ramp > 0.5:
            raise ValueError("contact_ramp must be >= 0 and short")
        if not (self.adapt_deadband >= 0.0 and self.adapt_filter >= 0.0 and self.max_adjustment > 0.0) or not math.isfinite(self.adapt_deadband + self.adapt_filter):
            raise ValueError(f"need finite adapt_deadband, adapt_filter >= 0 and max_adjustment > 0, got {self.adapt_deadband}, {self.adapt_filter}, {self.max_adjustment}")
        lateral = self.adapt_lateral_deadband
        if lateral is not None and not (math.isfinite(lateral) and lateral >= 0.0):
            raise ValueError(f"adapt_lateral_deadband must be None or a finite deadband >= 0 (m), got {lateral!r}")
        if not (math.isfinite(self.adapt_fade_delay) and self.adapt_fade_delay >= 0.0):
            raise ValueError(f"adapt_fade_delay must be finite and >= 0, got {self.adapt_fade_delay}")
        if not (math.isfinite(self.adapt_freeze_time) and self.adapt_freeze_time >= 0.0):
            raise ValueError(f"adapt_freeze_time must be finite and >= 0, got {self.adapt_freeze_time}")
        if not (self.adapt_full_error > self.adapt_deadband):
            raise ValueError(f"adapt_full_error must exceed adapt_deadband ({self.adapt_deadband}), got {self.adapt_full_error}")
        if not (0.0 <= self.recovery_reach <= 1.0):
            raise ValueError(f"recovery_reach must be in [0, 1] (a fraction of the straight leg), got {self.recovery_reach}")
        if not (0.0 <= self.recovery_max_crouch < 0.5):
            raise ValueError(f"recovery_max_crouch must be in [0, 0.5) m, got {self.recovery_max_crouch}")
        if not (math.isfinite(self.hip_roll_gain) and self.hip_roll_gain >= 0.0 and 0.0 < self.hip_roll_max < 0.5):
            raise ValueError(f"need a finite hip_roll_gain >= 0 (rad/m) and 0 < hip_roll_max < 0.5 rad, got {self.hip_roll_gain}, {self.hip_roll_max}")
        check_error_gate(self.hip_gate, "hip_gate")
        if not (math.isfinite(self.push_reach_speed) and self.push_reach_speed >= 0.0 and math.isfinite(self.push_reach_slack) and self.push_reach_slack >= 0.0):
            raise ValueError(f"need finite push_reach_speed >= 0 (m/s, 0: off) and push_reach_slack >= 0 (m), got {self.push_reach_speed}, {self.push_reach_slack}")
        if not (0.0 < self.push_min_swing <= self.min_swing):
            raise ValueError(f"push_min_swing must be in (0, min_swing = {self.min_swing}] s, got {self.push_min_swing}")
        if not (self.quick_land_margin > -0.5 and 0.0 < self.quick_land_time < 0.5 and 0.0 <= self.quick_land_reach < math.inf):
            raise ValueError(f"need quick_land_margin > -0.5 m (inf: off), quick_land_time in (0, 0.5) s and a finite quick_land_reach >= 0 m, got "
                             f"{self.quick_land_margin}, {self.quick_land_time}, {self.quick_land_reach}")
        if not 0.1 <= self.quick_land_width < 0.5:
            raise ValueError(f"quick_land_width must be in [0.1, 0.5) m, got {self.quick_land_width}")
        if not self.recovery_max_split > 0.2:
            raise ValueError(f"recovery_max_split must be > 0.2 m (inf: off), got {self.recovery_max_split}")
        if not self.recovery_walk_on >= 0.0:
            raise ValueError(f"recovery_walk_on must be >= 0 s (inf: off), got {self.recovery_walk_on}")
        if not self.walking_recovery_error > 0.0:
            raise ValueError(f"walking_recovery_error must be > 0 (m, inf: off), got {self.walking_recovery_error}")
        if not (self.push_swap_error > 0.0 and math.isfinite(self.push_swap_margin) and self.push_swap_margin >= 0.0):
            raise ValueError(f"need push_swap_error > 0 (m, inf: off) and a finite push_swap_margin >= 0 (m), got {self.push_swap_error}, {self.push_swap_margin}")
        if self.recovery_cop not in ("edge", "centre", "auto"):
            raise ValueError(f"recovery_cop must be 'edge', 'centre' or 'auto', got {self.recovery_cop!r}")
        if self.late_touchdown_force is not None and not (0.0 <= self.late_touchdown_force <= 1.0):
            raise ValueError(f"late_touchdown_force must be a fraction of the weight in [0, 1] or None, got {self.late_touchdown_force}")
        for name in ("lead_settle_time", "start_settle_time"):
            value = getattr(self, name)
            if not (value >= 0.0 and math.isfinite(value)):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")
        for name in ("landing_box", "recovery_landing_box"):
            box = getattr(self, name)
            if box is None and name == "recovery_landing_box":
                continue
            (x_lo, x_hi), (y_lo, y_hi) = box
            if not (x_lo < x_hi and 0.0 < y_lo < y_hi) or not all(math.isfinite(float(x)) for x in (x_lo, x_hi, y_lo, y_hi)):
                raise ValueError(f"{name} must be ((x_lo, x_hi), (y_lo, y_hi)) with x_lo < x_hi and 0 < y_lo < y_hi (left foot, stance frame), got {box}")

    def for_command(self, command: VelocityCommand) -> WalkerConfig:
        """The configuration that walks ``command`` (inside the gait's limits): this one (the same
        object) inside the base gait's limits; beyond them the gait of
        :meth:`~giwbc.locomotion.footsteps.GaitConfig.for_command` (faster cadence, longer steps),
        the shortest swing no longer than its single support and the landing box holding its
        longest, widest steps with today's margins around them."""
        gait = self.gait.for_command(command)
        if gait is self.gait:
            return self
        base = self.gait
        (x_lo, x_hi), (y_lo, y_hi) = self.landing_box
        box = (
            (min(x_lo, x_lo - (gait.max_step_backward - base.max_step_backward)), max(x_hi, x_hi + (gait.max_step_forward - base.max_step_forward))),
            (y_lo, max(y_hi, y_hi + (gait.max_extra_width - base.max_extra_width))),
        )
        return replace(self, gait=gait, min_swing=min(self.min_swing, gait.single_support), landing_box=box)


# The walker on an *estimated* state (deployment, or a policy trained for it). The estimator's sole
# forces come from the legs' joint efforts, quasi-statically: a swinging leg's own acceleration
# reads as up to ~60 N on its sole (measured on the emulated G1), above the default touch-down
# threshold (0.15 of the weight, ~50 N) late in a swing; deployed, a touch-down needs 0.35 of the
# weight (~120 N), which a real landing reaches within a few ms. The estimated DCM's velocity errs
# by a few cm/s around each touch-down (the stance foot rolls): the step adapter fed the raw
# estimate moved landings enough that the emulated G1 landed on a sole edge (ankle roll at its
# soft limit) within 2-3 steps at 0.3 m/s, so it sees the nominal DCM plus the low-passed error
# beyond a 3 cm deadband, and moves a landing at most 0.1 m from the plan. A softer swing foot
# (kp 250, not 400): with the process emulator's one-cycle reply delay the stiffer one landed on a
# sole edge after ~9 steps. From the planned touch-down on, 0.1 of the weight (on a sole down at the
# stance sole's height) counts as landed: see ``late_touchdown_force``. (tests/test_deploy_walk.py)
# m: the torsion the feet are built with when only WalkerConfig.recovery_torsion is set: the rows must exist
# to be tightened later, and at 1 m they never bind (a sole's friction pyramid alone keeps |τ_z| within
# μ (X + Y) f_z, ~0.07 f_z on the G1's sole).
TORSION_LOOSE = 1.0

DEPLOYMENT_OPTIONS: Mapping[str, Any] = MappingProxyType({
    "touchdown_force": 0.35, "swing_kp": 250.0, "adapt_deadband": 0.03, "adapt_filter": 0.02, "max_adjustment": 0.1,
    "start_settle_time": 0.5, "late_touchdown_force": 0.1,
    # The walking-push steps (issue 38) are measured on the MuJoCo ground truth only: off on the estimate.
    "walking_recovery_error": math.inf, "push_swap_error": math.inf,
})  # fmt: skip
# A floor the walker does not know to grip (a gym mat, rubber tiles, painted concrete: mu ~0.6) or feet it
# was not built for. With BalanceConfig's mu = 0.8 (each horizontal axis of the force pyramid; 1.13 along
# a diagonal) the WBC put 1.1x a foot's load tangentially on a foot ramping out and 0.47x on the stance
# foot at lift-off; on the plant variants (robots/g1/plants) the feet slid 50-300 mm in a 100 N push.
# mu = 0.5 plans inside any such floor; the softer swing (250, as deployed) because at 400 its lift-off
# asked the stance foot for more than 0.5 allows and the G1 drifted sideways (0.5 m/s: vy -0.02 m/s).
# Measured on the MuJoCo truth, tuning seeds 20001-20002, default -> any_floor: 100 N x 0.2 s standing
# pushes in 8 directions recovered 46 -> 70 of 80 on the capsule / point / rounded feet, soft floor
# and all_at_once plants (soft floor 5 -> 12 of 16), nominal 16 -> 16; walks (0.3, 0.5, -0.3 m/s,
# turning 0.3 rad/s, 12 s) fell 11 -> 1 of 56 on the 7 variants, 0 -> 0 of 8 nominal, per-step tracking
# RMS on the nominal plant 0.021 / 0.024 / 0.063 / 0.020 -> 0.015 / 0.032 / 0.041 / 0.021. Not the
# default: it gives up pushes a gripping floor allows (a 150 N back-diagonal push, lateral pushes while
# walking: tests/test_locomotion_recovery_reach.py, test_walk_lateral_push.py, test_deploy_walk.py fail
# with it). Both at once need the friction measured (slip detection), not assumed.
# With the estimator in the loop (G1Walk-v0, 0.3 m/s) the point-footed plants ended on an ankle roll's soft
# limit: a loaded foot rolled onto its toe-heel diagonal, and at a lift-off the QP's joint-limit bounds
# on its fast-turning ankle had no solution (the fallback let the ankle go). So any_floor also holds a
# rolled stance foot's CoP on its raised side (roll_cop_tilt 6 deg) and solves such a tick without the
# bounds (relax_joint_limits). Tuning seeds 20000-20003: ends on all_at_once + point_feet 7 -> 3 of 8;
# the nominal walk unchanged (no foot rolls 6 deg, no QP fails). README, "Plants the controller was not tuned on".
# A compliant floor turns a loaded stance foot under a yaw moment far inside its friction (MuJoCo's soft
# contact creeps: soft_floor, 5 -> 55 deg in 0.16 s under the 10-20 N m the WBC planned at each lift-off
# to hold the base's heading against the swinging leg, a fall two steps later). yaw_momentum_weight 3
# (giwbc.control.yaw_momentum) lets the trunk and arms take the swing leg's yaw momentum instead. Tuning
# seeds 20000-20001 (truth, 8 directions x 2 of 100 N x 0.2 s): pushes soft floor 12 -> 16, capsule feet
# 13 -> 16, point feet 14 -> 15 of 16; soft-floor walks (0.3 / 0.5 m/s, 20 s, 20000-20004) 3 -> 0 falls of 10.
# But at weight 3 the walker on the estimate (soft-limit ends counted, as a robot stops) ended 24 of 70 walks
# on the variants against 7 without (fresh seeds 64000-64009; a stance ankle roll past its limit, point feet
# 10 of 10): the truth benchmark counts falls only. Weight 0.3: 7 of 70 on the same seeds, and the estimator's
# errors within issue 41's bars on every plant (the soft floor's only with the task); on the truth (fresh
# 67500-67504) soft-floor walks 2 falls of 9 (3 without, 0 at weight 3), pushes of 40: soft floor 31 (30 / 38),
# capsule 38 (34 / 40), point feet 37 (32 / 40). README, "Where issue 41 stands".
# So the weight is 3 only where the floor is seen not to hold yaw or a push is being caught (yaw_slip_weight,
# yaw_slip_angle 10 deg: a single support's stance sole turns 1-5 deg on the box and point feet, 8-16 deg on
# the soft floor), 1 while catching a push (yaw_recovery_weight), 0.3 elsewhere. Tuning seeds 20000-20004
# (truth, soft-floor walks 20 s at 0.3 m/s): 1 -> 0 falls of 5; on the estimate (0.3 m/s, 20000-20003) point
# feet 0, capsule 0, all_at_once 3 of 4 (3 at 0.3 throughout). Pushes (20000-20001, 16 of 100 N), recovery
# weight 0.3 / 1 / 3: soft floor 10 / 15 / 15, point feet 16 / 15 / 14 (fresh 67600-67604 at 3: point feet
# 38 -> 33 of 40). README, "Plants the controller was not tuned on".
# On an estimated DCM (the deployment preset's 3 cm adapter deadband) a point foot's stance (all_at_once)
# kept a lateral DCM error of 1.5-5 cm over steps: inside the deadband, beyond what its ankle can take back
# (the DCM controller's CoP, 2.35x the error across the foot, sat on the sole's edge and the foot rolled onto
# it), so it grew until an ankle roll passed its soft limit. adapt_lateral_deadband 0: the lateral error
# reaches the step adapter whole (low-passed), the forward keeps the deadband. Tuning seeds 20000-20008
# (estimate, 0.3 m/s, 20 s): all_at_once ends 6 -> 2 of 9 (1 cm: 20000-20002 as 0); no effect on the truth.
# Fresh 64100-64109 (without yaw_slip_weight): ends on the variants 16 -> 9 of 70, but all_at_once 8 -> 7 and
# point feet 2 -> 2 (the foot still rocks), all_at_once's estimator tilt error 0.85 -> 1.21 deg; README.
ANY_FLOOR_OPTIONS: Mapping[str, Any] = MappingProxyType(
    {"friction": 0.5, "swing_kp": 250.0, "roll_cop_tilt": 6.0, "relax_joint_limits": True, "yaw_momentum_weight": 0.3,
     "yaw_slip_weight": 3.0, "yaw_slip_angle": 10.0, "yaw_recovery_weight": 1.0, "adapt_lateral_deadband": 0.0,
     "late_swing_push": True}
)
# late_swing_push (off by default, see its field): on in any_floor, where a soft floor's late, slipping step is
# caught as a walking push. Fresh 67900-67909 (truth, 10 x 20 s per command): soft floor at 0.3 m/s 1 fall of 10
# with it off, 0 on; every other plant and command bit for bit the same; on the estimate (64300-64309) the
# same ends either way.
WALKER_PRESETS: Mapping[str, Mapping[str, Any]] = MappingProxyType({"deployment": DEPLOYMENT_OPTIONS, "any_floor": ANY_FLOOR_OPTIONS})


def walker_config(options: "Mapping[str, Any] | str | None" = None, base: WalkerConfig | None = None) -> WalkerConfig:
    """A :class:`WalkerConfig` from ``options``: field values (a mapping), a preset's name
    (``"deployment"``: :data:`DEPLOYMENT_OPTIONS`, the walker on an estimated state; ``"any_floor"``:
    :data:`ANY_FLOOR_OPTIONS`, a floor or feet the walker was not tuned on), or None
    (the defaults); applied over ``base`` (default ``WalkerConfig()``)."""
    config = base if base is not None else WalkerConfig()
    if options is None:
        return config
    if isinstance(options, str):
        if options not in WALKER_PRESETS:
            raise ValueError(f"unknown walker preset {options!r}: choose one of {tuple(WALKER_PRESETS)} or give WalkerConfig fields")
        options = WALKER_PRESETS[options]
    unknown = set(options) - set(WalkerConfig.__dataclass_fields__)
    if unknown:
        raise ValueError(f"unknown WalkerConfig fields {sorted(unknown)}")
    return replace(config, **options)


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
    push_swaps: int = 0  # double supports where a push made the other foot step (WalkerConfig.push_swap_error)
    quick_landings: int = 0  # swings a walking push toward the stance side brought down at once (WalkerConfig.quick_land_margin)
    late_touchdowns: int = 0
    rolled_ticks: int = 0  # single-support ticks whose CoP a rolled stance foot moved (WalkerConfig.roll_cop_tilt)
    notes: list[str] = field(default_factory=list)
    # The swing target before and after the step residual (:meth:`~giwbc.locomotion.walker.WalkingController.set_step_residual`).
    planned_target: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    target: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    nominal_target: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))  # the plan's, before the step adapter
