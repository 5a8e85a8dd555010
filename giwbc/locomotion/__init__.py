"""Locomotion beneath the tasks, above the whole-body controller: walking and stepping.

One concept per module:

* :mod:`~giwbc.locomotion.planar` — plain-float 2-D arithmetic with numpy's bits (the per-tick hot paths);
* :mod:`~giwbc.locomotion.lipm` — LIPM / DCM closed forms (ω, ξ = c + ċ/ω, capture point);
* :mod:`~giwbc.locomotion.support` — support polygons (hull, inside test, clipping);
* :mod:`~giwbc.locomotion.dcm` — the DCM reference through a footstep plan, the DCM controller;
* :mod:`~giwbc.locomotion.footsteps` — footsteps from a velocity command, with limits;
* :mod:`~giwbc.locomotion.step_adapter` — where and when the next foot lands, from the measured DCM;
* :mod:`~giwbc.locomotion.swing` — swing-foot trajectories, re-targetable in flight;
* :mod:`~giwbc.locomotion.walker` — the walking / push-recovery controller on the WBC, made of:
  :mod:`~giwbc.locomotion.walker_config` (its phase, configuration and per-tick state),
  :mod:`~giwbc.locomotion.contact_schedule` (the phase machine: lift-off, touch-down, settling),
  :mod:`~giwbc.locomotion.swing_control` (the swing foot's trajectory, task and in-flight adaptation),
  :mod:`~giwbc.locomotion.push_recovery` (standing push detection and recovery steps),
  :mod:`~giwbc.locomotion.walker_references` (the DCM reference and pelvis heading),
  :mod:`~giwbc.locomotion.residuals` (a policy's corrections on top);
* :mod:`~giwbc.locomotion.simulation` — closed-loop MuJoCo runs of the walker (walks, pushes).

It may import :mod:`giwbc.control` and :mod:`giwbc.robot`, never the tasks, runtimes or apps.
"""

from giwbc.locomotion.dcm import CopSegment, DcmController, DcmReference
from giwbc.locomotion.footsteps import ClampedCommand, Footstep, FootstepPlanner, GaitConfig, VelocityCommand
from giwbc.locomotion.lipm import capture_point, dcm, dcm_at, natural_frequency
from giwbc.locomotion.step_adapter import StepAdapter, StepAdapterWeights, StepAdjustment
from giwbc.locomotion.swing import SwingTrajectory

__all__ = [
    "ClampedCommand",
    "CopSegment",
    "DcmController",
    "DcmReference",
    "Footstep",
    "FootstepPlanner",
    "GaitConfig",
    "StepAdapter",
    "StepAdapterWeights",
    "StepAdjustment",
    "SwingTrajectory",
    "VelocityCommand",
    "capture_point",
    "dcm",
    "dcm_at",
    "natural_frequency",
]
