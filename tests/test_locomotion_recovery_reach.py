"""Standing push recovery at the reach limit (giwbc.locomotion.walker): a recovering step that
reaches backward lowers the CoM so that the swing hip is within a straight leg's reach of the
landing spot (``recovery_reach``); a step stuck on the box's forward bound is timed from the sole's
centre (``recovery_cop="auto"``)."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from giwbc.locomotion.footsteps import Footstep
from giwbc.locomotion.lipm import natural_frequency
from giwbc.locomotion.simulation import Push, simulate_walk
from giwbc.locomotion.step_adapter import StepAdapter
from giwbc.locomotion.walker import WalkerConfig, WalkingController


def test_leg_geometry_is_each_legs_first_joint_and_the_straight_leg(g1):
    walker = WalkingController(g1)
    model = walker.model
    assert set(walker._hips) == {"left", "right"}
    for side, hip in walker._hips.items():
        assert model.parents[hip] == 1  # hangs from the floating base
        joint = walker.contacts[side].joint_id
        while joint > hip:  # the foot's joint descends from it
            joint = model.parents[joint]
        assert joint == hip
    # Standing, the hips are a little lower than a straight leg: bent knees, a few cm of slack only.
    walker.reset()
    hip_heights = [float(walker._data.oMi[h].translation[2]) - walker._ground for h in walker._hips.values()]
    assert all(0.9 * walker._leg_length < h < walker._leg_length for h in hip_heights)
    # The straight leg: every joint at zero, the hip-to-sole distance.
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    contact = walker.contacts["left"]
    sole = data.oMi[contact.joint_id] * contact.placement
    assert walker._leg_length == pytest.approx(float(np.linalg.norm(sole.translation - data.oMi[walker._hips["left"]].translation)), abs=1e-3)


@pytest.mark.parametrize("field, value", [("recovery_reach", -0.1), ("recovery_reach", 1.2), ("recovery_reach", math.nan),
                                          ("recovery_max_crouch", -0.01), ("recovery_cop", "middle")])
def test_bad_recovery_settings_are_refused(field, value):
    with pytest.raises(ValueError, match=field):
        WalkerConfig(**{field: value})


@pytest.mark.slow
def test_a_150_newton_back_diagonal_push_is_caught_by_a_crouched_step(g1):
    """30 N·s toward 159° (back and left; tuning seed 126 of the evaluate protocol). Standing tall
    the stepping leg is straight with its sole still ~3 cm above the floor at the planned
    touch-down: it lands ~0.08 s late and ~0.1 m past its spot, the split collapses. Lowering the
    CoM while the foot swings puts the spot within reach and the robot ends upright."""
    push = (Push(1.202, 150.0, math.radians(159.0)),)
    tall = simulate_walk(g1, (0.0, 0.0, 0.0), 2.6, pushes=push, command_start=None, seed=126, config=WalkerConfig(recovery_reach=0.0))
    crouched = simulate_walk(g1, (0.0, 0.0, 0.0), 2.6, pushes=push, command_start=None, seed=126, config=WalkerConfig())
    assert tall.fell
    assert not crouched.fell and crouched.recovery_steps >= 1 and crouched.final_tilt < 0.35


@pytest.mark.slow
def test_recovery_reach_leaves_walking_alone(g1):
    """The crouch acts only in a standing recovery: a walk is bit for bit the same without it."""
    a = simulate_walk(g1, (0.3, 0.0, 0.0), 2.0, config=WalkerConfig(recovery_reach=0.0), seed=3)
    b = simulate_walk(g1, (0.3, 0.0, 0.0), 2.0, config=WalkerConfig(), seed=3)
    assert a.steps == b.steps and np.array_equal(a.distance, b.distance) and np.array_equal(a.step_velocities, b.step_velocities)


def test_a_forward_saturated_step_predicted_from_the_sole_centre_touches_down_sooner():
    """``recovery_cop="auto"``: a recovery step stuck on the box's forward bound is re-solved with
    the CoP at the sole's centre. The DCM then runs on from farther behind it (ξ_end = p + (ξ − p)σ,
    a larger ξ − p), overshoots the front of the box more for the same σ, and the adapter answers
    with an earlier touch-down; the landing stays on the box's front edge."""
    omega = natural_frequency(0.68)
    adapter = StepAdapter(omega)
    stance = Footstep("right", [0.0, -0.12])
    box = ((-0.45, 0.5), (0.17, 0.75))  # left foot, stance frame
    dcm = np.array([0.3, -0.08])
    edge_cop = np.array([0.12, -0.08])  # the sole's front edge, nearest the DCM
    kwargs = dict(dcm=dcm, nominal_step=np.array([0.3, 0.12]), nominal_remaining=0.3, nominal_offset=np.array([0.0, -0.05]),
                  box=box, remaining_range=(0.05, 0.4))
    edge = adapter.adapt(stance, edge_cop, **kwargs)
    centre = adapter.adapt(stance, stance.position, **kwargs)
    assert stance.to_local(edge.position)[0] == pytest.approx(0.5) and stance.to_local(centre.position)[0] == pytest.approx(0.5)
    assert centre.remaining_time < edge.remaining_time - 0.01
