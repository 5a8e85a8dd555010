"""The contact schedule: a part of the walking controller
(:class:`~giwbc.locomotion.walker.WalkingController`, which mixes :class:`ContactSchedule` in; it
works on the controller's state).

A phase machine over :class:`~giwbc.locomotion.walker_config.Phase`: standing (no step planned) →
double support (the weight shifts; at its end the swing foot's contact is ramped out with the WBC's
force ramp) → single support (one foot swings) → touch-down (the contact made again, its force
ramped in) → double support … Touch-down is *early* when the foot's measured normal force exceeds
``touchdown_force`` after ``early_touchdown`` of the swing near the landing spot, *late* when it has
not by the planned time (the foot keeps descending, for at most ``late_touchdown`` s). A velocity
command starts a walk; the command back at zero brings the feet together and the walk settles;
a push standing starts recovery steps (:mod:`giwbc.locomotion.push_recovery`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from giwbc.locomotion.footsteps import Footstep, other_side, side_sign, wrap_angle
from giwbc.locomotion.planar import distance2
from giwbc.locomotion.walker_config import Phase


# The gait envelope's velocity correction (ContactSchedule._measure_velocity): touch-downs after a
# command before it measures, the fraction of the velocity error added per touch-down, its bound (m/s).
ENVELOPE_SETTLE_STEPS = 3
ENVELOPE_WINDOW_STEPS = 4  # steps (whole cycles: the feet's middle sways within one), the velocity is measured over
ENVELOPE_VELOCITY_GAIN = 0.3
ENVELOPE_MAX_CORRECTION = 0.25
ENVELOPE_DRIFT_GAIN = 0.2  # sideways or turning: the fraction of the velocity error added to the planner's offset per touch-down
ENVELOPE_MAX_DRIFT = 0.15  # m/s, the planner's offset (FootstepPlanner.offset) at most
ENVELOPE_MAX_TURN = 1.3  # the closed-loop heading's turn per step, at most this × the planned one


class ContactSchedule:
    """The walking controller's phase machine: lift-off, touch-down, settling (see the module docstring)."""

    def _advance(self, t: float, xi: np.ndarray, forces: Mapping[str, float]) -> None:
        """One tick of the schedule: start a walk or a recovery standing, lift off at the end of a
        double support, adapt the step and detect touch-down in single support."""
        cfg = self.config
        if self._phase is Phase.STAND:
            if self.walking:
                first = self.planner.first_swing_side(self.command)
                self._begin_double(t, stance=other_side(first), duration=cfg.start_shift)
            elif self._pushed(t, xi):
                self._start_recovery(t, xi)
            return
        if self._phase is Phase.DOUBLE:
            if self.walking:
                self._walking_push(t, xi)  # a push: the other foot may step now, or the recovery's steps take over
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
        if self.walking and (t < self._swing.t1 - 0.03 or cfg.late_swing_push):
            self._walking_push(t, xi)  # (late_swing_push: to the touch-down, the late wait included)
        if cfg.step_adaptation and t < self._swing.t1 - 0.03:
            self._adapt_step(t, xi)
        # A quick landing (push_recovery) counts from its touch-down time on once the sole is down, loaded
        # or not: its stance foot is tipping away from it, and it would wait out late_touchdown unloaded.
        quick = t >= self._swing.t1 and self._quick_land is not None and self._quick_land[0] == self._phase_start
        # A walking recovery's swing past its planned touch-down lands as a quick landing does (WalkerConfig.late_swing_push).
        quick = quick or (t >= self._swing.t1 and cfg.late_swing_push and self._recovering and self.walking)
        late = t >= self._swing.t1 and (cfg.late_touchdown_force is not None or quick)
        threshold = 0.0 if quick else cfg.late_touchdown_force if late else cfg.touchdown_force
        # (The force is read once it can count: a walker's step() reads the robot only when asked.)
        landed = elapsed >= cfg.early_touchdown * (self._swing.t1 - self._phase_start) and forces.get(swing, 0.0) >= threshold * self.weight
        if landed and late:  # a light load counts only on a sole down at the stance sole's height
            height = self._sole_world(swing).translation[2] - self._sole_world(self._stance).translation[2]
            landed = height < cfg.late_touchdown_height
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
        """Lift-off: the swing foot's target (the plan's next step, or the recovery landing) and
        duration, its trajectory and task, and the single-support DCM reference."""
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
            target, duration = self.planner.next_step(anchor, self.command, self._leading_yaw(t, anchor)), cfg.gait.single_support
        target = self.planner.constrain(stance_foot, target)
        self._nominal_feet[swing] = target
        self._nominal_target = target
        self.state.planned_target = target.position
        target = self._apply_step_offset(stance_foot, target)
        self.state.target = target.position
        self._swing_nominal = duration
        duration = self._swing_duration(duration)
        self._phase_end = t + duration
        self._swing = self._launch_swing(t, swing, target, duration)
        self._target = target
        self.state.nominal_target = self._nominal_target.position
        reference = self._plan_single(t, target, t + duration)
        self._nominal_offset = reference.dcm_at_segment_end(0) - target.position
        if self._recovering:
            self._nominal_offset = -side_sign(swing) * cfg.recovery_offset * np.array([-math.sin(target.yaw), math.cos(target.yaw)])
        self._reference = self._step_reference = reference
        self._dcm_shaper.reset()
        self._lateral_shaper.reset()
        self._engage_swing_task(t, swing)

    def _leading_yaw(self, t: float, anchor: Footstep) -> float | None:
        """A leading turning step's yaw relative to ``anchor``, every gait (None: the plan's
        ``2 · yaw_rate · T``): towards the heading the command's yaw rate reaches one step period
        from now, counted from the first such step — the steps last longer than planned (the step
        adapter lengthens them: 0.36 s for a planned 0.28 s turning at 1 rad/s), and a fixed yaw per
        step turned 20 % slower than asked."""
        command = self.command
        if command.yaw_rate == 0.0 or command.yaw_rate * side_sign(other_side(anchor.side)) <= 0.0:
            return None
        if self._yaw_goal is None:
            self._yaw_goal = (t, anchor.yaw)
        start, yaw = self._yaw_goal
        period = self.config.gait.step_period
        turn = wrap_angle(yaw + command.yaw_rate * (t - start + period) - anchor.yaw)
        # At most ENVELOPE_MAX_TURN × the planned turn, the heading goal held back to it (no catch-up
        # after a push: turning 1.0 rad/s, 80 N sideways, 3 of 4 runs fell 0.5-1 s after the push).
        bound = ENVELOPE_MAX_TURN * 2.0 * abs(command.yaw_rate) * period
        if abs(turn) > bound:
            turn = math.copysign(bound, turn)
            self._yaw_goal = (t, anchor.yaw + turn - command.yaw_rate * period)
        return turn

    def _measure_velocity(self, t: float) -> None:
        """At a touch-down while walking (every gait: the base gait's 0.3 m/s walked 0.33, -0.3 walked
        -0.40, tuning seed 1; corrected 0.308 and -0.294): the walk's forward velocity over the last
        ``ENVELOPE_WINDOW_STEPS`` steps (the feet's middle, in their mean heading) against the
        command's; the planner's correction (:attr:`~giwbc.locomotion.footsteps.FootstepPlanner.correction`,
        the steps' and the DCM preview's) integrates the difference, ``ENVELOPE_VELOCITY_GAIN`` of it
        per touch-down within ``ENVELOPE_MAX_CORRECTION``, after ``ENVELOPE_SETTLE_STEPS`` touch-downs.
        The step adapter lands the envelope's steps where the DCM goes: walking backward at 0.5 m/s,
        0.24 m for 0.17 m planned (-0.61 m/s; corrected -0.52, tuning seed 1). A command with a
        lateral or turning component is corrected in both axes by the planner's offset
        (:attr:`~giwbc.locomotion.footsteps.FootstepPlanner.offset`, ``ENVELOPE_DRIFT_GAIN`` within
        ``ENVELOPE_MAX_DRIFT``), measured on the CoM step by step; a straight one as before."""
        if distance2(self.state.dcm, self.state.dcm_ref) > self.config.stiff_swing_error:
            # Pushed: the measurement restarts (a push's velocity is not the gait's: walking backward
            # at 0.5 m/s, 80 N forward, the integrated push fell 3 s later).
            self._touchdowns.clear()
            return
        left, right = self.feet["left"], self.feet["right"]
        middle = 0.5 * (left.position + right.position)
        heading = left.yaw + 0.5 * wrap_angle(right.yaw - left.yaw)
        self._touchdowns.append((t, middle, heading, self._com[:2].copy()))
        if len(self._touchdowns) < ENVELOPE_SETTLE_STEPS + 2:
            return
        first = max(ENVELOPE_SETTLE_STEPS, len(self._touchdowns) - 1 - ENVELOPE_WINDOW_STEPS)
        if ENVELOPE_WINDOW_STEPS % 2:
            raise AssertionError("the velocity window must span whole cycles")
        command, (cx, cy) = self.command, self.planner.correction
        limit = ENVELOPE_MAX_CORRECTION
        if command.vy == 0.0 and command.yaw_rate == 0.0:
            if command.vx == 0.0:
                return
            t0, middle0, heading0, _ = self._touchdowns[first]
            mean = heading0 + 0.5 * wrap_angle(heading - heading0)
            c, s = math.cos(mean), math.sin(mean)
            dx, dy = (float(middle[0]) - float(middle0[0])) / (t - t0), (float(middle[1]) - float(middle0[1])) / (t - t0)
            cx = min(max(cx + ENVELOPE_VELOCITY_GAIN * (command.vx - (c * dx + s * dy)), -limit), limit)
            self.planner.correction = (cx, cy)
            return
        # Sideways or turning: the CoM's velocity along and across the heading, step by step (each
        # step's displacement in its own mean heading: over a turned window the chord alone reads 8 %
        # slow at 1 rad/s; the CoM, not the feet's middle: on the feet's, (0.5, 0.2, 0) walked vy 0.171,
        # on the CoM's 0.192), both corrected by the planner's offset (a zero component too: the drift
        # of a turning walk; tuning seed 20500, 12 s: (0.3, 0.2, 0.5) walked vy 0.14 -> 0.19,
        # (-0.108, 0, 0.5) drifted 0.045 -> -0.013, (0.5, 0.2, 0) vx 0.464 -> 0.479).
        along = across = 0.0
        for (_, _, h0, m0), (_, _, h1, m1) in zip(self._touchdowns[first:-1], self._touchdowns[first + 1:]):
            mean = h0 + 0.5 * wrap_angle(h1 - h0)
            c, s = math.cos(mean), math.sin(mean)
            ddx, ddy = float(m1[0]) - float(m0[0]), float(m1[1]) - float(m0[1])
            along += c * ddx + s * ddy
            across += -s * ddx + c * ddy
        span = t - self._touchdowns[first][0]
        along, across = along / span, across / span
        ox, oy = self.planner.offset
        gain, bound = ENVELOPE_DRIFT_GAIN, ENVELOPE_MAX_DRIFT
        # Beside a lateral command, the forward only while the lateral is followed (longer steps cost
        # lateral: (0.5, 0.2, 0) walked vy 0.144 with both integrating, tuning seed 20501).
        if command.vy == 0.0 or abs(command.vy - across) <= max(0.05 * abs(command.vy), 0.03):
            ox = min(max(ox + gain * (command.vx - along), -bound), bound)
        oy = min(max(oy + gain * (command.vy - across), -bound), bound)
        self.planner.offset = (ox, oy)

    def _touch_down(self, t: float) -> None:
        """The swing foot landed (or ran out of time): its contact ramps in; then settle, or the
        next double support (short after a push)."""
        cfg = self.config
        swing = other_side(self._stance)
        self._remove_swing_task(self.swing_tasks[swing])
        self.wbc.add_contact(self.contacts[swing], ramp_time=cfg.contact_ramp)
        self.feet[swing] = self._measured_foot(swing)
        self._polygons = {}
        self.state.steps += 1
        self._swing = None
        if self._recovering:
            self._recovery_touch_down(t, swing)
            return
        self._measure_velocity(t)
        if not self.walking and self._feet_together():
            self._settle(t)
            self._lead_after = t + cfg.lead_settle_time
            return
        # A large DCM error (a push) shortens the double support to the force ramp: the next
        # foot gets going at once.
        error = float(np.linalg.norm(self.state.dcm - self.state.dcm_ref))
        duration = cfg.gait.double_support if error < cfg.hurry_error else max(cfg.contact_ramp, 1e-3)
        self._begin_double(t, stance=swing, duration=duration)

    def _settle(self, t: float) -> None:
        """Stand: double support, no step planned."""
        self._phase, self._phase_start, self._phase_end = Phase.STAND, t, math.inf
        self._reference = None

    def _feet_together(self) -> bool:
        """The feet side by side at about the nominal width (a stop)."""
        left, right = self.feet["left"], self.feet["right"]
        local = right.to_local(left.position)
        return abs(local[0]) < 0.03 and abs(local[1] - self.config.gait.step_width) < 0.03
