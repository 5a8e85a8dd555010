"""The swing foot in flight: a part of the walking controller
(:class:`~giwbc.locomotion.walker.WalkingController`, which mixes :class:`SwingControl` in; it works on
the controller's state).

At lift-off the swing sole gets a trajectory (:mod:`giwbc.locomotion.swing`) to its landing spot
and its SE3 pose task enters the WBC (low weight walking, stiff recovering or once the DCM error
is large); each tick the task follows the trajectory (a late foot keeps descending), and the step
adapter (:mod:`giwbc.locomotion.step_adapter`) moves the landing spot and the touch-down time from
the measured DCM, re-targeting the trajectory in flight. At touch-down the task leaves the QP.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from giwbc.control.tasks import FramePoseTask
from giwbc.locomotion.footsteps import Footstep, other_side, wrap_angle
from giwbc.locomotion.planar import distance2
from giwbc.locomotion.step_adapter import StepFrame, bounded_box
from giwbc.locomotion.swing import SwingTrajectory


class SwingControl:
    """The walking controller's swing trajectory, swing sole task and in-flight step adaptation."""

    def _launch_swing(self, t: float, swing: str, target: Footstep, duration: float) -> SwingTrajectory:
        """The ``swing`` sole's trajectory from where it is now to ``target`` (``touchdown_depth``
        below the stance sole) over ``duration`` s."""
        cfg = self.config
        start = self._sole_world(swing)
        rotation = start.rotation
        start_pose = np.array([start.translation[0], start.translation[1], start.translation[2], math.atan2(rotation[1, 0], rotation[0, 0])])
        yaw = start_pose[3] + wrap_angle(target.yaw - start_pose[3])
        ground = self._sole_world(self._stance).translation[2]
        return SwingTrajectory(t, t + duration, start_pose, np.array([*target.position, ground - cfg.touchdown_depth, yaw]), apex=cfg.swing_apex)

    def _engage_swing_task(self, t: float, swing: str) -> None:
        """Put the ``swing`` sole's pose task in the QP, stiff while recovering, at its reference for ``t``."""
        cfg = self.config
        task = self.swing_tasks[swing]
        task.set_weight(cfg.recovery_swing_weight if self._recovering else cfg.swing_weight)
        self._swing_reference(t)
        self.wbc.add_task(task)

    def _adapt_step(self, t: float, xi: np.ndarray) -> None:
        """In flight: the step adapter moves the landing spot and the touch-down time from the measured
        DCM; the swing is re-targeted (and the DCM reference re-planned) when they moved."""
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
        if task.weight[0] < cfg.recovery_swing_weight and distance2(xi, self.state.dcm_ref) > cfg.stiff_swing_error:
            task.set_weight(cfg.recovery_swing_weight)  # pushed: the foot must get where the adapter sends it
        if cfg.adapt_freeze_time > 0.0 and t >= self._swing.t1 - cfg.adapt_freeze_time:
            return  # the last moments of the swing: the landing is held (WalkerConfig.adapt_freeze_time)
        shaper = self._dcm_shaper
        dcm = shaper(t, xi, self._step_reference.evaluate(t)[0]) if shaper.active and self._step_reference is not None else xi
        if cfg.adapt_lateral_deadband is not None and shaper.active and self._step_reference is not None:
            dcm = self._lateral_error_through(t, xi, dcm, stance.yaw)
        frame, box = self._step_frame(stance, swing)
        adjustment = self._landing_adjustment(t, stance, dcm, frame, box, remaining_range)
        target = Footstep(swing, adjustment.position, self._nominal_target.yaw)
        self.state.planned_target = target.position
        target = self._apply_step_offset(stance, target)
        self.state.target = target.position
        touchdown = t + adjustment.remaining_time
        moved = distance2(target.position, self._target.position) > 2e-3 or abs(touchdown - self._swing.t1) > 4e-3  # type: ignore[union-attr]
        if moved:
            full = np.array([*target.position, self._swing.target[2], self._swing.target[3]])
            self._swing.retarget(t, full, touchdown)
            self._target = target
            planned = self._planned_for
            if planned is None or distance2(target.position, planned[0]) > cfg.replan_distance or abs(self._swing.t1 - planned[1]) > cfg.replan_time:
                self._reference = self._plan_single(t, target, self._swing.t1)

    def _lateral_error_through(self, t: float, xi: np.ndarray, dcm: np.ndarray, yaw: float) -> np.ndarray:
        """``dcm`` (what the adapter sees) with its part across the stance heading ``yaw`` replaced by
        the nominal DCM's plus the measured ``xi``'s lateral error through the lateral shaper
        (``WalkerConfig.adapt_lateral_deadband``, low-passed over ``adapt_filter``)."""
        nominal = self._step_reference.evaluate(t)[0]  # type: ignore[union-attr]
        nx, ny = -math.sin(yaw), math.cos(yaw)  # the stance heading's left
        error = nx * float(xi[0] - nominal[0]) + ny * float(xi[1] - nominal[1])
        shaped = self._lateral_shaper(t, np.array([nominal[0] + nx * error, nominal[1] + ny * error]), nominal)
        kept = nx * float(dcm[0] - nominal[0]) + ny * float(dcm[1] - nominal[1])
        lateral = nx * float(shaped[0] - nominal[0]) + ny * float(shaped[1] - nominal[1])
        return np.array([float(dcm[0]) + nx * (lateral - kept), float(dcm[1]) + ny * (lateral - kept)])

    def _step_frame(self, stance: Footstep, swing: str) -> tuple[StepFrame, tuple[tuple[float, float], tuple[float, float]]]:
        """The step adapter's per-step part and the landing box: made at the step's first
        adaptation, reused while the stance foot, the nominal step, its DCM offset and the
        recovery flag stay the same objects (they change only at lift-off and touch-down)."""
        cached = self._step_frames
        if cached is not None:  # (the key's five identities compared in line: a generator over zip cost ~2 µs a tick)
            held = cached[0]
            if held[0] is stance and held[1] is self._nominal_target and held[2] is self._nominal_offset and held[3] is self._recovering and held[4] is swing:
                return cached[1], cached[2]
        key = (stance, self._nominal_target, self._nominal_offset, self._recovering, swing)
        assert self._nominal_target is not None
        box = bounded_box(self._landing_box(swing), stance.to_local(self._nominal_target.position), self.config.max_adjustment)
        frame = StepFrame(stance, self._nominal_target.position, self._nominal_offset)
        self._step_frames = (key, frame, box)
        return frame, box

    def _remove_swing_task(self, task: FramePoseTask) -> None:
        """Take a swing sole's task out of the QP (if it is there)."""
        if any(existing is task for existing in self.wbc.tasks):
            self.wbc.remove_task(task.name)

    def _swing_reference(self, t: float) -> None:
        """The swing sole task's reference (ankle pose, twist, acceleration) from the swing trajectory
        at ``t``; past the planned touch-down the foot keeps descending at ``descent_speed``."""
        swing = other_side(self._stance)
        assert self._swing is not None
        # (Plain floats: the same numbers as the swing's evaluate() arrays.)
        (px, vx, ax), (py, vy, ay), (pz, vz, az_), (yaw, wz, az) = self._swing.state_rows(t)
        if t > self._swing.t1:  # late: keep descending
            late = t - self._swing.t1
            pz -= self.config.descent_speed * late
            vz = -self.config.descent_speed
        c, s = math.cos(yaw), math.sin(yaw)
        rotation = self._swing_rotation  # (a rotation about z, its four entries written in place: pin.SE3 copies it)
        rotation[0, 0], rotation[0, 1], rotation[1, 0], rotation[1, 1] = c, -s, s, c
        sole = pin.SE3(rotation, np.array([px, py, pz]))
        ankle = sole * self._sole_inverse[swing]
        # The ankle origin's velocity and acceleration (the sole turns about z only).
        ankle_xy = ankle.translation[:2].tolist()
        lx, ly = ankle_xy[0] - px, ankle_xy[1] - py
        # ω × r and α × r + ω × (ω × r) for ω, α along z
        twist = np.array([vx - wz * ly, vy + wz * lx, vz, 0.0, 0.0, wz])
        accel = np.array([ax - az * ly - wz * wz * lx, ay + az * lx - wz * wz * ly, az_, 0.0, 0.0, az])
        self.swing_tasks[swing].set_reference(ankle, twist, accel)
