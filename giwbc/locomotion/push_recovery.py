"""Standing push recovery by stepping: a part of the walking controller
(:class:`~giwbc.locomotion.walker.WalkingController`, which mixes :class:`PushRecovery` in; it works on
the controller's state).

**Detecting the push.** Each tick estimates what the LIPM does not explain — the disturbance
``d = ξ̇ − ω (ξ − p)`` — and, standing, a step starts when the capture point, led by that
disturbance held a little longer (a push still acting), leaves the support polygon by
``push_margin``.

**The recovery steps.** The foot whose step keeps the predicted DCM closest to what the robot can
still stand on steps first; it aims at the capture point predicted for its touch-down, shifted
outward by ``recovery_offset``, in the (wider) recovery landing box; the step adapter refines the
landing with the CoP held on the stance sole's edge nearest the DCM (or its centre, see
``recovery_cop``), at most ``recovery_max_split`` from the stance sole's centre (the box's corners are
beyond the leg's reach; the other foot steps next if the DCM runs on). While a foot swings *backward*, the CoM height reference drops so that the
landing spot stays within the leg's reach (the reach crouch). At each touch-down the recovery
settles once the capture point is back inside both feet, or the other foot steps on.

**Pushes while walking** (or stepping in place; issue 38). Unhandled, a push at the wrong moment
failed in one of a few ways: toward the stance side, the swinging foot (which cannot cross the
stance leg) finished its swing at the narrowest width and the other foot stepped a whole step
later, into a 0.7 m split with the DCM still outside it; in double support, the foot the plan had
next stepped inward first; forward, the adapter asked for the landing box's front edge in the
shortest swing and the foot came down 0.27 m short and late. Now a DCM error (with the disturbance
lead) beyond ``walking_recovery_error`` hands the steps to the recovery above — the foot on the
push's side steps now in double support, a swinging foot comes down on the adapter's spot and the
other steps on — with only the force ramp between steps, then the walk goes on; below it, in double
support, ``push_swap_error`` may swap the feet's roles. A push toward the stance side while a foot swings (the DCM with
the lead ``quick_land_margin`` outward of the stance sole) is a two-step catch with no crossing: the swinging foot comes
down at once beside the stance foot (the quick landing, ``quick_land_width`` from it), and the stance foot steps out
next, its reach from the DCM. The adapter can also keep a pushed landing
within the swinging foot's reach (``push_reach_speed``, :class:`~giwbc.locomotion.step_adapter.SwingReach`; off by default).
"""

from __future__ import annotations

import math

import numpy as np

from giwbc.locomotion.footsteps import Footstep, other_side, side_sign
from giwbc.locomotion.planar import distance2, rotate
from giwbc.locomotion.step_adapter import StepAdjustment, StepFrame, SwingReach
from giwbc.locomotion.support import clip_to_polygon, signed_distance
from giwbc.locomotion.walker_config import Phase


class PushRecovery:
    """The walking controller's push detection and recovery steps (see the module docstring)."""

    # --- detecting a push ------------------------------------------------------------------------
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
        px, py = float(previous[0]), float(previous[1])
        rx, ry = (float(xi[0]) - px) / dt, (float(xi[1]) - py) / dt
        smoothed = self._xi_rate
        if smoothed is not None:
            alpha = dt / (self.config.disturbance_time + dt)
            sx, sy = float(smoothed[0]), float(smoothed[1])
            rx, ry = sx + alpha * (rx - sx), sy + alpha * (ry - sy)
        self._xi_rate = np.array([rx, ry])
        omega, cop = self.omega, self._last_cop
        self.state.disturbance = np.array([rx - omega * (px - float(cop[0])), ry - omega * (py - float(cop[1]))])

    def _disturbance_lead(self) -> np.ndarray:
        """The DCM shift a disturbance ``d`` held for ``disturbance_horizon`` more seconds adds to
        any later prediction: with the CoP held at ``p``, ``ξ(T) = p + (ξ + (d/ω)(1 − e^{−ωτ}) − p) e^{ωT}``
        for ``T ≥ τ`` — the measured DCM plus this lead, in the same closed form."""
        cfg = self.config
        if not cfg.use_disturbance:
            return np.zeros(2)
        return self.state.disturbance / self.omega * (1.0 - math.exp(-self.omega * cfg.disturbance_horizon))

    def _led(self, xi: np.ndarray) -> tuple[float, float]:
        """``xi + self._disturbance_lead()`` on floats, the same operations (every tick's push checks)."""
        x, y = float(xi[0]), float(xi[1])
        cfg = self.config
        if not cfg.use_disturbance:
            return x + 0.0, y + 0.0
        omega = self.omega
        factor = 1.0 - math.exp(-omega * cfg.disturbance_horizon)
        dx, dy = self.state.disturbance.tolist()
        return x + dx / omega * factor, y + dy / omega * factor

    def _pushed(self, t: float, xi: np.ndarray) -> bool:
        """Standing: the capture point ``xi`` (plus the disturbance lead, unless a walk stopped less
        than ``lead_settle_time`` ago) is ``push_margin`` outside the support polygon."""
        cfg = self.config
        return signed_distance(self._led(xi) if cfg.trigger_lead and t >= self._lead_after else xi, self.support_polygon()) > cfg.push_margin

    # --- the recovery steps ----------------------------------------------------------------------
    def _start_recovery(self, t: float, xi: np.ndarray) -> None:
        """A short double support (the force ramp), then the chosen foot steps."""
        cfg = self.config
        swing = self._recovery_swing_side(xi)
        self._recovering = True
        self._nominal_feet = {}
        self._begin_double(t, stance=other_side(swing), duration=max(cfg.contact_ramp, 1e-3))
        self.state.recovery_steps += 1

    def _recovery_swing_side(self, xi: np.ndarray) -> str:
        """Which foot steps when the capture point ``xi`` left the polygon: for each choice of
        stance foot, the CoP goes to the point of its sole nearest ``xi`` and the DCM runs on for
        the shortest swing (``ξ_T = p + (ξ − p) e^{ωT}``); the choice whose ``ξ_T`` stays closest
        to what it can still stand on — the stance sole, or the landing box of the other foot —
        wins. (The foot the capture point passed on the outside steps out when it is far past;
        when it is only just past, that foot carries and the other closes up.)"""
        return self._swing_scores(xi)[0]

    def _swing_scores(self, xi: np.ndarray) -> tuple[str, dict[str, float]]:
        """:meth:`_recovery_swing_side`'s choice and each swing side's score (m: how far the
        predicted DCM ends out of what that choice can still stand on)."""
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
        return min(scores, key=lambda side: (scores[side], side)), scores

    def _predict_recovery(self, stance: Footstep, horizon: float) -> Footstep:
        """Where a recovering foot goes: on the capture point ``horizon`` s ahead with the CoP on
        the stance sole, shifted outward by ``recovery_offset`` (the step adapter refines it)."""
        swing = other_side(stance.side)
        xi = self.state.dcm
        predicted = stance.position + (xi - stance.position) * math.exp(self.omega * horizon)
        outward = side_sign(swing) * self.config.recovery_offset * np.array([-math.sin(stance.yaw), math.cos(stance.yaw)])
        return Footstep(swing, predicted + outward, stance.yaw)

    def _landing_box(self, swing: str) -> tuple[tuple[float, float], tuple[float, float]]:
        """The stance-frame box the ``swing`` foot may land in (the recovery box while recovering)."""
        cfg = self.config
        box = cfg.recovery_landing_box if self._recovering and cfg.recovery_landing_box is not None else cfg.landing_box
        (x_lo, x_hi), (y_lo, y_hi) = box
        return ((x_lo, x_hi), (y_lo, y_hi)) if side_sign(swing) > 0 else ((x_lo, x_hi), (-y_hi, -y_lo))

    def _landing_adjustment(self, t: float, stance: Footstep, dcm: np.ndarray, frame: StepFrame, box: tuple[tuple[float, float], tuple[float, float]],
                            remaining_range: tuple[float, float]) -> StepAdjustment:
        """The step adapter's landing and touch-down for the DCM ``dcm``, with the CoP held where the
        DCM controller will hold it: the stance sole's centre walking; recovering, per ``recovery_cop``
        (``frame``: the adapter's per-step part, :meth:`_step_frame`)."""
        cfg = self.config
        # Recovering, the DCM controller holds the CoP on the stance sole's edge nearest the DCM
        # (clipped there), not at its centre: predicting from the centre overstated the DCM's run by
        # (edge - centre)(e^{ωT} - 1), up to ~0.1 m, and the foot landed that much too far outward
        # (feet 0.6-0.75 m apart, the pelvis rolled over; 100 N, tuning seeds 0-199: 199/200 vs
        # 185/200; 150 N, 0-99: 67 vs 68; adding the disturbance lead as well: 34/100 at 150 N).
        assert self._nominal_target is not None
        if self._recovering and self.walking and self._quick_landing(t, stance):
            return self._quick_adjustment(t, stance, frame, box)
        edge = self._recovering and cfg.recovery_cop != "centre"
        cop_hold = clip_to_polygon(dcm, self.support_polygon((self._stance,))) if edge else stance.position
        reach = None
        if self.walking and cfg.push_reach_speed > 0.0 and (self._recovering or distance2(self.state.dcm, self.state.dcm_ref) > cfg.stiff_swing_error):
            # Pushed while walking: a landing the foot reaches, as soon as push_min_swing after lift-off.
            foot = stance.to_local(self._sole_world(other_side(stance.side)).translation[:2])
            reach = SwingReach(float(foot[0]), float(foot[1]), cfg.push_reach_speed, cfg.push_reach_slack)
            remaining_range = (max(cfg.push_min_swing - (t - self._phase_start), 0.02), remaining_range[1])
        adjustment = self.adapter.adapt_in(frame, cop_hold, dcm, self._phase_end - t, box, remaining_range, reach)  # type: ignore[union-attr]
        if edge and cfg.recovery_cop == "auto" and float(stance.to_local(adjustment.position)[0]) >= box[0][1] - 1e-6:
            adjustment = self.adapter.adapt_in(frame, stance.position, dcm, self._phase_end - t, box, remaining_range)  # type: ignore[union-attr]
        if self._recovering and math.isfinite(cfg.recovery_max_split):
            adjustment = self._within_split(stance, adjustment, box)
        return adjustment

    def _within_split(self, stance: Footstep, adjustment: StepAdjustment, box: tuple[tuple[float, float], tuple[float, float]]) -> StepAdjustment:
        """``adjustment`` with its landing drawn toward the stance sole's centre to at most ``recovery_max_split``
        from it (the landing box's narrowest width kept), the touch-down time unchanged: the box's corners
        are beyond the leg's reach."""
        x, y = (float(v) for v in stance.to_local(adjustment.position))
        split = math.hypot(x, y)
        limit = self.config.recovery_max_split
        if split <= limit:
            return adjustment
        (_, _), (y_lo, y_hi) = box
        scale = limit / split
        return adjustment.landing_moved(x * scale, min(max(y * scale, y_lo), y_hi))

    # --- the quick landing (a walking push toward the stance side) --------------------------------
    def _quick_landing(self, t: float, stance: Footstep) -> bool:
        """Whether the swinging foot lands at once (:attr:`~giwbc.locomotion.walker_config.WalkerConfig.quick_land_margin`):
        the DCM plus the disturbance lead is that far outward of the ``stance`` sole's centre line, on
        the side the swinging foot cannot reach without crossing the stance leg. Decided once per
        swing: held to its touch-down."""
        cfg = self.config
        if not math.isfinite(cfg.quick_land_margin):
            return False
        if self._quick_land is not None and self._quick_land[0] == self._phase_start:
            return True
        led = stance.to_local(np.array(self._led(self.state.dcm)))
        if side_sign(stance.side) * float(led[1]) <= cfg.quick_land_margin:
            return False
        elapsed = t - self._phase_start
        self._quick_land = (self._phase_start, t + max(cfg.push_min_swing - elapsed, cfg.quick_land_time))
        self.state.quick_landings += 1
        return True

    def _quick_adjustment(self, t: float, stance: Footstep, frame: StepFrame, box: tuple[tuple[float, float], tuple[float, float]]) -> StepAdjustment:
        """The quick landing: beside the stance foot at the box's narrowest width (or ``quick_land_width``), along it at the led
        DCM's place within ``quick_land_reach`` of the foot's own, at the touch-down decided."""
        cfg = self.config
        assert self._quick_land is not None
        swing = other_side(stance.side)
        foot = stance.to_local(self._sole_world(swing).translation[:2])
        led = stance.to_local(np.array(self._led(self.state.dcm)))
        (x_lo, x_hi), (y_lo, y_hi) = box
        y = min(y_lo, cfg.quick_land_width) if side_sign(swing) > 0 else max(y_hi, -cfg.quick_land_width)
        fx = float(foot[0])
        x = min(max(float(led[0]), fx - cfg.quick_land_reach, x_lo), fx + cfg.quick_land_reach, x_hi)
        wx, wy = rotate(frame.c, frame.s, x, y)
        return StepAdjustment(np.array([frame.ox + wx, frame.oy + wy]), max(self._quick_land[1] - t, 0.02), frame, (float(led[0]), float(led[1]), x, y))

    # --- pushes while walking ----------------------------------------------------------------------
    def _walking_push(self, t: float, xi: np.ndarray) -> None:
        """Walking or stepping in place, in double or single support: a push beyond
        ``walking_recovery_error`` hands the steps to the standing recovery's (its choice of foot,
        landing box, CoP on the stance edge, stiff swing) until the capture point is back inside the
        feet, then the walk goes on; a smaller one may swap the feet's roles (:meth:`_push_swap`)."""
        cfg = self.config
        if self._recovering:
            return
        if math.isfinite(cfg.walking_recovery_error) and distance2(self._led(xi), self.state.dcm_ref) > cfg.walking_recovery_error:
            self._recovering = True
            self._nominal_feet = {}
            self.state.recovery_steps += 1
            if self._phase is Phase.DOUBLE:
                swing = self._recovery_swing_side(xi)
                planned = other_side(self._stance)
                if self._lift_off_issued and swing != planned:
                    self.wbc.add_contact(self.contacts[planned], ramp_time=cfg.contact_ramp)
                    self._begin_double(t, stance=other_side(swing), duration=max(cfg.contact_ramp, 1e-3))
                elif not self._lift_off_issued:
                    self._begin_double(t, stance=other_side(swing), duration=max(cfg.contact_ramp, 1e-3))
            elif self._phase is Phase.SINGLE and self._target is not None:
                swing = other_side(self._stance)
                self.swing_tasks[swing].set_weight(cfg.recovery_swing_weight)
                yaw = self._target.yaw
                self._nominal_offset = -side_sign(swing) * cfg.recovery_offset * np.array([-math.sin(yaw), math.cos(yaw)])
            return
        if self._phase is Phase.DOUBLE:
            self._push_swap(t, xi)

    def _push_swap(self, t: float, xi: np.ndarray) -> None:
        """Walking, in double support: a push that the foot about to swing cannot catch (it would
        have to cross the other leg) swaps the feet's roles — the foot on the push's side steps now,
        after the force ramp (:attr:`~giwbc.locomotion.walker_config.WalkerConfig.push_swap_error`)."""
        cfg = self.config
        if self._recovering or not math.isfinite(cfg.push_swap_error) or self._phase_start == self._swap_at:
            return  # (one swap per double support: the one it started)
        if distance2(self._led(xi), self.state.dcm_ref) < cfg.push_swap_error:
            return
        planned = other_side(self._stance)
        best, scores = self._swing_scores(xi)
        if best == planned or scores[planned] <= scores[best] + cfg.push_swap_margin:
            return
        if self._lift_off_issued:  # the planned swing foot's force was ramping out: back in
            self.wbc.add_contact(self.contacts[planned], ramp_time=cfg.contact_ramp)
        self._begin_double(t, stance=planned, duration=max(cfg.contact_ramp, 1e-3))
        self._swap_at = t
        self.state.push_swaps += 1

    # --- the reach crouch -------------------------------------------------------------------------
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

    # --- settling ---------------------------------------------------------------------------------
    def _recovery_touch_down(self, t: float, landed: str) -> None:
        """A recovering foot (``landed``) touched down: settle if the capture point is back inside
        both feet; otherwise the other foot steps."""
        cfg = self.config
        # (Measured on the tuning seeds at 150 N, no better: a shorter double support between
        # recovery steps, 26/40 vs 26/40; closing up a split wider than 0.45 m first, 22/40 vs 25/40.)
        if signed_distance(self.state.dcm, self.support_polygon()) > -cfg.settle_margin:
            # Feet alternate: the one just landed carries, the other closes up or steps on (walking:
            # at once, after the force ramp — a push while walking has had the time of a step already).
            double = max(cfg.contact_ramp, 1e-3) if self.walking else max(cfg.gait.double_support, cfg.contact_ramp)
            self._begin_double(t, stance=landed, duration=double)
            self.state.recovery_steps += 1
        elif self.walking and math.isfinite(cfg.recovery_walk_on):
            # Walking: the walk goes on from here, the foot just landed carrying and the other stepping
            # after a short double support (a nominal step: it closes the recovery's split).
            self._recovering = False
            self._begin_double(t, stance=landed, duration=max(cfg.recovery_walk_on, cfg.contact_ramp, 1e-3))
        else:
            self._recovering = False
            self._settle(t)
