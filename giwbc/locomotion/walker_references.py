"""The walking controller's references for the WBC: a part of
:class:`~giwbc.locomotion.walker.WalkingController`, which mixes :class:`WalkerReferences` in (it
works on the controller's state).

The DCM reference (:mod:`giwbc.locomotion.dcm`) through the landing spots ahead — standing, the
middle of the feet; in double support a CoP ramp that starts where the reference meets the
measured DCM, then the preview of ``preview_steps`` steps (or, stopping, the closing step and
rest between the feet); in single support re-planned when the step adapter moved the landing —
and the pelvis heading, the mean of the feet's (the swing target's while it flies).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from giwbc.locomotion.dcm import CopSegment, DcmReference, walking_cop_plan
from giwbc.locomotion.footsteps import Footstep, VelocityCommand, other_side, wrap_angle
from giwbc.locomotion.lipm import cop_start_for_dcm
from giwbc.locomotion.residuals import error_gate
from giwbc.locomotion.support import clip_to_polygon
from giwbc.locomotion.walker_config import Phase


class WalkerReferences:
    """The walking controller's DCM reference planning and pelvis heading (see the module docstring)."""

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
        """Feet at ``a`` and ``b`` side by side at about the nominal width."""
        local = b.to_local(a.position)
        return abs(local[0]) < 0.03 and abs(abs(local[1]) - self.config.gait.step_width) < 0.03

    def _plan_single(self, t: float, target: Footstep, touchdown: float) -> DcmReference:
        """The DCM reference from ``t``: the CoP on the stance sole until ``touchdown`` at ``target``,
        then through the preview (or to rest between the feet when the walk stops)."""
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
                    tail = DcmReference(rest, self.omega)
                    start = clip_to_polygon(cop_start_for_dcm(xi, duration, tail.initial[0], stance.position, self.omega), self.support_polygon())
                    self._reference = DcmReference.before(CopSegment(duration, start, stance.position), tail, t)
                else:
                    self._reference = DcmReference([CopSegment(duration, start, stance.position)], self.omega, t)
            xi_ref, rate, _ = self._reference.evaluate(t)
            return xi_ref, rate, self.support_polygon()
        # Single support: the stance sole only; the swing sole follows its trajectory.
        assert self._swing is not None and self._reference is not None
        self._swing_reference(t)
        xi_ref, rate, _ = self._reference.evaluate(t)
        return xi_ref, rate, self.support_polygon((self._stance,))

    def _hip_roll_reference(self, xi: np.ndarray, xi_ref: np.ndarray) -> float:
        """The hip strategy's pelvis roll for this tick (``WalkerConfig.hip_roll_gain`` plus a policy's
        hip residual; 0 when both are zero, standing before the first step, or inside the gate)."""
        cfg = self.config
        gain = cfg.hip_roll_gain + self._hip_gain_offset
        if gain == 0.0 or (self._phase is Phase.STAND and not self.state.steps) or not math.isfinite(self._heading):
            return 0.0
        ex, ey = float(xi[0] - xi_ref[0]), float(xi[1] - xi_ref[1])
        gate = error_gate(math.hypot(ex, ey), *cfg.hip_gate)
        if gate == 0.0:
            return 0.0
        across = -math.sin(self._heading) * ex + math.cos(self._heading) * ey  # left of the heading
        return gate * min(max(-gain * across, -cfg.hip_roll_max), cfg.hip_roll_max)

    def _heading_reference(self, hip_roll: float = 0.0) -> None:
        """Pelvis upright, heading the mean of the feet's (the swing target's while it flies);
        rolled by ``hip_roll`` rad (the hip strategy) on top of a policy's orientation residual."""
        left, right = self.feet["left"].yaw, self.feet["right"].yaw
        if self._phase is Phase.SINGLE and self._target is not None:
            if self._target.side == "left":
                left = self._target.yaw
            else:
                right = self._target.yaw
        yaw = left + 0.5 * wrap_angle(right - left)
        if yaw == self._heading and not self._orientation_changed and hip_roll == self._hip_roll:
            return
        self._heading = yaw
        self._orientation_changed = False
        self._hip_roll = hip_roll
        c, s = math.cos(yaw), math.sin(yaw)
        rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        offset = self._orientation_offset
        if hip_roll != 0.0:
            offset = np.array([hip_roll, 0.0, 0.0]) if offset is None else offset + np.array([hip_roll, 0.0, 0.0])
        if offset is not None:
            rotation = rotation @ pin.rpy.rpyToMatrix(offset)
        self.balance.base_task.set_reference(pin.SE3(rotation, np.zeros(3)))
