"""The gait envelope beyond the base gait's limits (issue 38, item 3): faster cadence and longer,
wider, more turned steps for commands beyond the base limits; the base gait, bit for bit, inside
them; the clamp at the envelope's edge said."""

from __future__ import annotations

import hashlib
import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from giwbc.apps.walk import followed_command
from giwbc.locomotion.footsteps import Footstep, FootstepPlanner, GaitConfig, GaitEnvelope, VelocityCommand, side_sign
from giwbc.locomotion.simulation import simulate_walk
from giwbc.locomotion.walker_config import WalkerConfig
from giwbc.robot import load

BASE = GaitConfig(envelope=None)  # today's gait: no envelope


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def _inside_commands() -> list[VelocityCommand]:
    """A grid over the base limits' box, its corners and faces included."""
    limits = BASE.base_limits()
    axes = [sorted({lo, 0.5 * lo, 0.0, 0.5 * hi, hi}) for lo, hi in limits.values()]
    return [VelocityCommand(*c) for c in itertools.product(*axes)]


def test_inside_the_base_limits_the_gait_and_the_walker_config_are_the_same_objects():
    gait, config = GaitConfig(), WalkerConfig()
    assert gait.base_limits() == BASE.base_limits()
    for command in _inside_commands():
        assert gait.envelope_fraction(command) == 0.0
        assert gait.for_command(command) is gait
        assert config.for_command(command) is config
        unbounded = FootstepPlanner(replace(gait, backward_turning=None))  # (backward while turning: its own bound, below)
        assert unbounded.clamp(command).command == command  # not clamped, same values


def test_backward_while_turning_is_clamped_and_said():
    """(-0.3, 0, 0.5) is inside the base gait's box, but backward while turning is bounded
    (``GaitConfig.backward_turning``): the backward speed gives way, the turn stays, a note says so."""
    planner = FootstepPlanner()
    base = planner.config.base_limits()
    clamped = planner.clamp((-0.3, 0.0, 0.5))
    expected = -base["vx"][0] * (planner.config.backward_turning - 0.5 / base["yaw_rate"][1])
    assert clamped.command.vx == pytest.approx(-expected) and clamped.command.yaw_rate == 0.5
    assert len(clamped.notes) == 1 and "backward while turning" in clamped.notes[0] and f"{-expected:.3g}" in clamped.notes[0]
    assert planner.clamp((-0.3, 0.0, 0.1)).command == VelocityCommand(-0.3, 0.0, 0.1)  # within the bound
    assert planner.clamp((0.3, 0.0, 0.5)).command == VelocityCommand(0.3, 0.0, 0.5)  # forward: no bound


def test_beyond_the_base_limits_the_cadence_quickens_towards_the_envelope_edge():
    gait = GaitConfig()
    envelope = gait.envelope
    assert envelope is not None
    base_back = -gait.base_limits()["vx"][0]
    periods = []
    for vx in np.linspace(base_back, envelope.backward, 6)[1:]:
        adapted = gait.for_command(VelocityCommand(-float(vx), 0.0, 0.0))
        assert adapted is not gait and adapted.envelope is None
        periods.append(adapted.step_period)
        # the step the command needs fits the adapted gait's limits (the planner does not cut it)
        assert vx * adapted.step_period <= adapted.max_step_backward + 1e-12
    assert all(a > b for a, b in zip(periods, periods[1:]))  # shorter steps the faster
    assert periods[0] < gait.step_period
    assert periods[-1] == pytest.approx(envelope.single_support + envelope.double_support)
    # the edge of every widened axis reaches the edge cadence; the largest fraction of any axis decides
    for command in [(-envelope.backward, 0.0, 0.0), (0.0, 0.0, envelope.turning), (0.3, 0.1, -envelope.turning)]:
        assert gait.envelope_fraction(VelocityCommand(*command)) == pytest.approx(1.0)
    config = WalkerConfig().for_command(VelocityCommand(-envelope.backward, 0.0, 0.0))
    assert config.min_swing <= config.gait.single_support <= config.max_swing
    (x_lo, _), (_, _) = config.landing_box
    assert x_lo <= -config.gait.max_step_backward  # the longest backward step lands inside the box


@pytest.mark.parametrize("command", [(-0.5, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (0.3, 0.0, 0.9), (-0.4, 0.15, 0.0), (-0.45, -0.11, 0.0), (0.4, -0.1, 0.8), (0.0, 0.15, -0.7)])
def test_envelope_plans_alternate_never_cross_and_average_to_the_command(command):
    planner = FootstepPlanner()
    gait = planner.config.for_command(VelocityCommand(*command))
    stance = Footstep("right", [0.0, -gait.step_width / 2])
    steps, notes = planner.plan(stance, command, 20)
    assert not notes
    feet = [stance] + steps
    for a, b in zip(feet, feet[1:]):
        assert a.side != b.side
        local, yaw = a.relative(b)
        lateral = local[1] * side_sign(b.side)
        assert gait.min_width - 1e-12 <= lateral <= gait.step_width + gait.max_extra_width + 1e-12
        assert -gait.max_step_backward - 1e-12 <= local[0] <= gait.max_step_forward + 1e-12
        assert abs(yaw) <= gait.max_step_yaw + 1e-12 and yaw * side_sign(b.side) >= -gait.max_inward_yaw
    T = gait.step_period
    yaw_rate = (np.unwrap([f.yaw for f in feet])[-1] - feet[0].yaw) / (len(steps) * T)
    assert yaw_rate == pytest.approx(command[2], abs=0.5 / len(steps))
    if command[2] == 0.0:
        mid0 = 0.5 * (feet[0].position + feet[1].position)
        mid1 = 0.5 * (feet[-1].position + feet[-2].position)
        np.testing.assert_allclose((mid1 - mid0) / ((len(steps) - 1) * T), command[:2], atol=0.2 / len(steps))


def test_a_command_beyond_the_envelope_is_clamped_at_its_edge_and_said():
    gait = GaitConfig()
    envelope = gait.envelope
    assert envelope is not None
    limits = gait.limits()
    base = gait.base_limits()
    assert limits["yaw_rate"] == (-envelope.turning, envelope.turning) and limits["vy"] == base["vy"]  # sideways: not widened
    assert limits["vx"] == (-envelope.backward, base["vx"][1])  # forward: not widened
    followed, notes = followed_command((3.0, -0.9, 2.5))  # at the turning edge: the others at 40 % of their base limits
    share = 1.0 - envelope.combined
    assert followed == (pytest.approx(share * base["vx"][1]), pytest.approx(share * base["vy"][0]), envelope.turning)
    assert len(notes) == 5 and all("clamped" in note for note in notes) and "vy = -0.9" in notes[1] and "40%" in notes[-1]
    for corner in [(-0.5, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 0.0, 1.0), (-0.5, share * base["vy"][1], 0.0)]:  # followed as asked
        assert followed_command(corner) == (corner, [])
    # today's limits, without an envelope
    assert FootstepPlanner(BASE).clamp((0.0, 0.0, 1.0)).command.yaw_rate == pytest.approx(BASE.max_step_yaw / (2 * BASE.step_period))


def test_an_envelope_whose_steps_do_not_fit_is_refused_in_one_line():
    with pytest.raises(ValueError, match="lateral .* needs a step of .* max_extra_width"):
        GaitConfig(envelope=GaitEnvelope(lateral=0.6))
    with pytest.raises(ValueError, match="finite and > 0"):
        GaitEnvelope(turning=math.nan)


def _trajectory(g1, command: tuple[float, float, float], config: WalkerConfig, seconds: float) -> tuple[str, np.ndarray]:
    digest = hashlib.sha256()
    last: list[np.ndarray] = []

    def observe(robot, controller) -> None:
        q, v = robot.generalized_state()
        digest.update(q.tobytes())
        digest.update(v.tobytes())
        last[:] = [q]

    simulate_walk(g1, command, seconds, seed=0, config=config, observe=observe)
    return digest.hexdigest(), last[0]


@pytest.mark.parametrize("vx", [0.3, 0.5])
def test_walks_inside_the_base_limits_are_bit_for_bit_those_without_an_envelope(g1, vx):
    """Every physics step's state of a walk at 0.3 and 0.5 m/s with the envelope (default) equals the
    one of today's gait without it. (Before the envelope, 4 s at seed 0 hashed 70dc9199… and
    e4a5c72f…; with it, the same.)"""
    with_envelope = _trajectory(g1, (vx, 0.0, 0.0), WalkerConfig(), 2.5)
    without = _trajectory(g1, (vx, 0.0, 0.0), WalkerConfig(gait=BASE), 2.5)
    assert with_envelope[0] == without[0]
    assert np.array_equal(with_envelope[1], without[1])
    assert with_envelope[1][0] > 0.3 * vx  # it walked


def test_envelope_turning_in_place_turns_the_feet_about_their_middle():
    """At 1 rad/s in place the envelope's plan keeps the point between the feet where it is (the
    base gait's turns about the stance sole walk it forward by ~width × yaw rate / 2)."""
    planner = FootstepPlanner()
    envelope_gait = planner.config.for_command(VelocityCommand(0.0, 0.0, 1.0))
    assert envelope_gait.turn_about_centre and not BASE.turn_about_centre
    stance = Footstep("right", [0.0, -planner.config.step_width / 2])
    steps, _ = planner.plan(stance, (0.0, 0.0, 1.0), 12)
    middles = [0.5 * (a.position + b.position) for a, b in zip([stance] + steps, steps)]
    np.testing.assert_allclose(middles[1::2], np.zeros((6, 2)), atol=1e-12)  # after every trailing step
    base_steps, _ = FootstepPlanner(BASE).plan(stance, (0.0, 0.0, 0.5), 12)
    assert np.linalg.norm(0.5 * (base_steps[-1].position + base_steps[-2].position)) < 0.05  # the base gait's: compensated
    raw = FootstepPlanner(BASE).cycle_velocity(VelocityCommand(0.0, 0.0, 0.5))
    assert raw[0] > 0.05  # (uncompensated, its turns about the stance sole walk it forward)


@pytest.mark.parametrize("command", [(0.5, 0.0, 0.5), (0.5, 0.0, -0.5), (0.0, 0.0, 0.5), (0.3, 0.1, -0.4), (-0.2, 0.1, 0.3), (0.4, 0.0, 0.8)])
def test_turning_plans_walk_the_linear_velocity_asked_in_the_feet_heading(command):
    """A turning plan's feet's middle, seen in the feet's mean heading, goes at the command's
    (vx, vy) over a cycle once compensated (uncompensated the base gait's (0.5, 0, 0.5) drifts 0.06 m/s
    sideways); a straight command is planned as it is."""
    planner = FootstepPlanner()
    gait = planner.config.for_command(VelocityCommand(*command))
    planner = FootstepPlanner(gait)
    asked = VelocityCommand(*command)
    compensated = planner.turn_compensated(asked)
    assert compensated.yaw_rate == asked.yaw_rate
    # (0.015: turning in place the lateral step pattern flips with the sign of a tiny vy, 0.007-0.013 m/s is left)
    np.testing.assert_allclose(planner.cycle_velocity(compensated), command[:2], atol=0.015)
    if command == (0.5, 0.0, 0.5):
        assert abs(planner.cycle_velocity(asked)[1]) > 0.05
    # Backward turning without a lateral command: no lateral lead against the turn's, the vx is compensated, a drift is left.
    backward = planner.turn_compensated(VelocityCommand(-0.2, 0.0, 0.4))
    assert backward.vy == 0.0 and planner.cycle_velocity(backward)[0] == pytest.approx(-0.2, abs=0.01)
    stance = Footstep("right", [0.0, -0.12])
    straight = VelocityCommand(0.4, 0.1, 0.0)
    assert planner.next_step(stance, straight).position.tolist() == planner._step(stance, straight, None).position.tolist()


def test_a_leading_yaw_replaces_the_planned_turn_within_the_step_limits():
    gait = GaitConfig().for_command(VelocityCommand(0.0, 0.0, 1.0))
    planner = FootstepPlanner(gait)
    stance = Footstep("right", [0.0, -0.12], 0.2)
    assert planner.next_step(stance, VelocityCommand(0.0, 0.0, 1.0), leading_yaw=0.5).yaw == pytest.approx(0.7)
    assert planner.next_step(stance, VelocityCommand(0.0, 0.0, 1.0), leading_yaw=5.0).yaw == pytest.approx(0.2 + gait.max_step_yaw)
    assert planner.next_step(stance, VelocityCommand(0.0, 0.0, -1.0), leading_yaw=0.5).yaw == pytest.approx(0.2)  # a trailing step follows


@pytest.mark.slow
def test_the_g1_turns_at_one_radian_per_second_in_place(g1):
    """1 rad/s (the base gait stops at 0.54): no fall, the mean yaw rate after 3 s within 5 %
    (the closed-loop heading), the base within 0.05 m/s of standing still, the joints inside their limits."""
    rates, velocities, joints = [], [], []

    def observe(robot, controller) -> None:
        if robot.time() >= 3.0:
            base = robot.base_state()
            rates.append(base.angular_velocity[2])
            velocities.append(base.linear_velocity[:2])
            joints.append(robot.generalized_state()[0][7:])

    run = simulate_walk(g1, (0.0, 0.0, 1.0), 7.0, seed=0, observe=observe)
    assert not run.fell and not run.notes
    assert np.mean(rates) == pytest.approx(1.0, rel=0.05)
    assert np.linalg.norm(np.mean(velocities, axis=0)) < 0.05
    lower, upper = g1.position_limits
    assert np.all(np.array(joints) > lower) and np.all(np.array(joints) < upper)  # inside the G1's joint limits


def test_the_planner_correction_moves_only_non_zero_components_by_at_most_half():
    planner = FootstepPlanner(GaitConfig().for_command(VelocityCommand(-0.5, 0.0, 0.0)))
    assert planner.corrected(VelocityCommand(-0.5, 0.0, 0.3)) == VelocityCommand(-0.5, 0.0, 0.3)  # none by default
    planner.correction = (0.2, -0.3)
    assert planner.corrected(VelocityCommand(-0.5, 0.0, 0.3)) == VelocityCommand(-0.3, 0.0, 0.3)
    assert planner.corrected(VelocityCommand(-0.3, 0.4, 0.0)) == VelocityCommand(-0.15, 0.2, 0.0)  # half at most: the sign stays
    stance = Footstep("right", [0.0, -0.12])
    step = planner.next_step(stance, VelocityCommand(-0.5, 0.0, 0.0))
    assert stance.to_local(step.position)[0] == pytest.approx(-0.3 * planner.config.step_period)


@pytest.mark.slow
def test_the_g1_walks_backward_at_the_envelope_edge_within_five_percent(g1):
    """-0.5 m/s (the base gait stops at -0.33 and overshoots by ~30 %): the velocity correction brings
    the mean after 3 s within 5 % of the command; no fall; the joints inside their limits."""
    velocities, joints = [], []

    def observe(robot, controller) -> None:
        if robot.time() >= 3.0:
            velocities.append(robot.base_state().linear_velocity[:2])
            joints.append(robot.generalized_state()[0][7:])

    run = simulate_walk(g1, (-0.5, 0.0, 0.0), 10.0, seed=1, observe=observe)
    assert not run.fell and not run.notes
    mean = np.mean(velocities, axis=0)
    assert mean[0] == pytest.approx(-0.5, rel=0.05) and abs(mean[1]) < 0.05
    lower, upper = g1.position_limits
    assert np.all(np.array(joints) > lower) and np.all(np.array(joints) < upper)  # inside the G1's joint limits


def test_beside_a_widened_component_the_others_shrink_and_it_is_said():
    """(0.5, -0.1, 0.8) with the full base limits beside the envelope fell (fresh seed 40001): beyond
    the base limits in one component, the others get at most (1 - combined x its fraction) of theirs."""
    planner = FootstepPlanner()
    gait = planner.config
    assert gait.envelope is not None
    clamped = planner.clamp((0.5, -0.1, 0.8))
    fraction = gait.envelope_fraction(VelocityCommand(0.0, 0.0, 0.8))
    share = 1.0 - gait.envelope.combined * fraction
    command = clamped.command
    assert command.vx == pytest.approx(share * gait.base_limits()["vx"][1]) and (command.vy, command.yaw_rate) == (-0.1, 0.8)
    assert len(clamped.notes) == 1 and "vx = 0.5 with yaw_rate = 0.8" in clamped.notes[0] and f"{share:.0%}" in clamped.notes[0]
    assert not planner.clamp((0.4, 0.0, 0.8)).notes  # within the share: as asked
    # at the base limits' edge the share is whole: continuous with the base box
    edge = gait.base_limits()["yaw_rate"][1]
    assert planner.clamp((0.6, 0.2, edge)).command == VelocityCommand(0.6, 0.2, edge)
    assert planner.clamp((0.6, 0.2, edge + 1e-6)).command.vx == pytest.approx(0.6, abs=1e-4)
    with pytest.raises(ValueError, match="combined"):
        GaitEnvelope(combined=1.5)


def _heading_frame_mean(after: float) -> tuple[list, object]:
    """An ``observe`` hook summing the base's heading-frame (vx, vy) and yaw rate after ``after`` s."""
    rows: list = []

    def observe(robot, controller) -> None:
        if robot.time() >= after:
            base = robot.base_state()
            c, s = base.rotation[0, 0], base.rotation[1, 0]
            norm = math.hypot(c, s)
            v = base.linear_velocity
            rows.append(((c * v[0] + s * v[1]) / norm, (-s * v[0] + c * v[1]) / norm, base.angular_velocity[2]))

    return rows, observe


@pytest.mark.slow
def test_the_g1_walks_forward_while_turning_without_sideways_drift(g1):
    """(0.5, 0, 0.5) (before the turning compensation and the base gait's closed-loop heading it walked
    (0.53, -0.10, 0.47): 0.1 m/s sideways): the mean after 3 s within 5 % of vx and the yaw rate, and
    within 0.03 m/s of no sideways motion; no fall."""
    rows, observe = _heading_frame_mean(3.0)
    run = simulate_walk(g1, (0.5, 0.0, 0.5), 9.0, seed=1, observe=observe)
    assert not run.fell and not run.notes
    vx, vy, wz = np.mean(rows, axis=0)
    assert vx == pytest.approx(0.5, rel=0.05) and wz == pytest.approx(0.5, rel=0.05)
    assert abs(vy) < 0.03


def _cycle_velocity(planner: FootstepPlanner, command: VelocityCommand, steps: int = 12) -> np.ndarray:
    """The feet's middle's velocity (m/s) over the last cycle of ``steps`` planned steps, in the feet's mean heading."""
    half = 0.5 * planner.config.step_width
    feet = {"left": Footstep("left", [0.0, half]), "right": Footstep("right", [0.0, -half])}
    stance = feet["right"] if planner.first_swing_side(command) == "left" else feet["left"]
    poses = []
    for _ in range(steps):
        stance = planner.next_step(stance, command)
        feet[stance.side] = stance
        left, right = feet["left"], feet["right"]
        poses.append((0.5 * (left.position + right.position), left.yaw + 0.5 * (right.yaw - left.yaw)))
    (m0, h0), (m1, h1) = poses[-3], poses[-1]
    heading = 0.5 * (h0 + h1)
    d = (m1 - m0) / (2.0 * planner.config.step_period)
    return np.array([math.cos(heading) * d[0] + math.sin(heading) * d[1], -math.sin(heading) * d[0] + math.cos(heading) * d[1]])


def test_the_planner_offset_moves_every_landing_in_the_steps_heading_and_the_plans_velocity_by_itself():
    """The walker's drift correction (FootstepPlanner.offset): each landing moved by offset x T along
    and across the step's mean heading, a zero command component included (the correction of the
    command's components cannot move those); the turn compensation does not undo it, so a turning
    plan's cycle velocity goes by the offset."""
    planner = FootstepPlanner(BASE)
    T = BASE.step_period
    stance = Footstep("right", [0.1, -0.12], 0.3)
    command = VelocityCommand(0.3, 0.0, 0.4)
    plain = planner.next_step(stance, command)
    planner.offset = (-0.05, 0.1)
    moved = planner.next_step(stance, command)
    heading = 0.3 + 0.5 * (plain.yaw - 0.3)
    c, s = math.cos(heading), math.sin(heading)
    assert moved.yaw == plain.yaw and moved.side == plain.side
    assert moved.position == pytest.approx(plain.position + T * np.array([c * -0.05 - s * 0.1, s * -0.05 + c * 0.1]), abs=1e-12)
    for command in (VelocityCommand(0.3, 0.0, 0.4), VelocityCommand(0.0, 0.08, -0.5), VelocityCommand(0.3, 0.15, 0.0)):
        planner.offset = (0.0, 0.0)
        before = _cycle_velocity(planner, command)
        planner.offset = (-0.05, 0.1)
        after = _cycle_velocity(planner, command)
        assert after - before == pytest.approx([-0.05, 0.1], abs=0.01)


@pytest.mark.slow
def test_the_g1_walks_a_lateral_and_turning_command_within_five_percent(g1):
    """(0.3, 0.2, 0.5): forward, sideways and turning at once (before the drift correction it walked
    (0.317, 0.13, 0.50): the lateral 35 % short): the mean after 3 s within 5 % (or 0.03 m/s) of each
    component; no fall."""
    rows, observe = _heading_frame_mean(3.0)
    run = simulate_walk(g1, (0.3, 0.2, 0.5), 10.0, seed=1, observe=observe)
    assert not run.fell and not run.notes
    mean = np.mean(rows, axis=0)
    command = np.array([0.3, 0.2, 0.5])
    assert np.all(np.abs(mean - command) <= np.maximum(0.05 * command, 0.03)), mean
