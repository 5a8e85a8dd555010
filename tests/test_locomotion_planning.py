"""Footstep planner (limits, alternation, no crossing, bad commands), step adapter (the foot
lands on the capture-point offset it is given; timing absorbs what the box cannot), swing
trajectories (continuity, rest at lift-off and touch-down, re-targeting in flight)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion.footsteps import Footstep, FootstepPlanner, GaitConfig, VelocityCommand, side_sign
from giwbc.locomotion.lipm import dcm_at, natural_frequency
from giwbc.locomotion.step_adapter import DcmErrorShaper, StepAdapter, StepAdapterWeights, StepFrame, bounded_box, solve_box_qp, solve_step_qp, step_qp_matrices
from giwbc.locomotion.swing import SwingTrajectory, quintic
from giwbc.locomotion.walker import WalkerConfig

OMEGA = natural_frequency(0.68)


# --- footsteps -----------------------------------------------------------------------------------
@pytest.mark.parametrize("command", [(0.4, 0.0, 0.0), (0.0, 0.15, 0.0), (0.0, -0.15, 0.0), (0.2, 0.0, 0.5), (0.1, -0.1, -0.4), (-0.2, 0.0, 0.0), (0.0, 0.0, 0.0)])
def test_plan_alternates_feet_keeps_width_and_averages_to_the_command(command):
    gait = GaitConfig()
    planner = FootstepPlanner(gait)
    stance = Footstep("right", [0.0, -gait.step_width / 2])
    steps, notes = planner.plan(stance, command, 20)
    assert not notes
    feet = [stance] + steps
    for a, b in zip(feet, feet[1:]):
        assert a.side != b.side  # alternating
        local, yaw = a.relative(b)
        lateral = local[1] * side_sign(b.side)
        assert gait.min_width - 1e-12 <= lateral <= gait.step_width + gait.max_extra_width + 1e-12  # never crosses
        assert -gait.max_step_backward - 1e-12 <= local[0] <= gait.max_step_forward + 1e-12
        assert abs(yaw) <= gait.max_step_yaw + 1e-12
        assert yaw * side_sign(b.side) >= -gait.max_inward_yaw  # never turned towards the other foot
    # Average body velocity over 20 steps, from the midpoints of consecutive feet, in the initial frame.
    T = gait.step_period
    mid0 = 0.5 * (feet[0].position + feet[1].position)
    mid1 = 0.5 * (feet[-1].position + feet[-2].position)
    yaw_rate = (np.unwrap([f.yaw for f in feet])[-1] - feet[0].yaw) / (len(steps) * T)
    assert yaw_rate == pytest.approx(command[2], abs=0.5 / len(steps))
    if command[2] == 0.0:
        velocity = (mid1 - mid0) / ((len(steps) - 1) * T)
        np.testing.assert_allclose(velocity, command[:2], atol=0.2 / len(steps))


def test_commands_beyond_limits_are_clamped_with_a_note_and_nan_refused():
    planner = FootstepPlanner(GaitConfig(envelope=None))  # the base gait's box (the envelope's clamp: tests/test_gait_envelope.py)
    lo, hi = planner.limits()["vx"]
    clamped = planner.clamp((5.0, 0.0, -9.0))
    assert clamped.command.vx == pytest.approx(hi) and clamped.command.yaw_rate == pytest.approx(planner.limits()["yaw_rate"][0])
    assert len(clamped.notes) == 2 and "vx = 5" in clamped.notes[0] and "clamped" in clamped.notes[0]
    steps, notes = planner.plan(Footstep("left", [0, 0.12]), (5.0, 0.0, 0.0), 2)
    assert notes and hi * planner.config.step_period == pytest.approx(steps[0].to_local(steps[1].position)[0])  # the forward edge's step
    assert hi == pytest.approx(planner.config.max_forward_speed) and hi * planner.config.step_period < planner.config.max_step_forward
    for bad in [(math.nan, 0, 0), (0, math.inf, 0), (0, 0, -math.inf)]:
        with pytest.raises(ValueError, match="finite"):
            planner.plan(Footstep("left", [0, 0.12]), bad, 3)
    with pytest.raises(ValueError):
        VelocityCommand("fast", 0.0, 0.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        Footstep("middle", [0, 0])
    with pytest.raises(ValueError):
        GaitConfig(min_width=0.3, step_width=0.2)


def test_constrain_moves_a_crossing_step_back_to_its_side():
    planner = FootstepPlanner()
    stance = Footstep("right", [0.0, -0.12], 0.3)
    crossing = Footstep("left", stance.to_world([0.1, -0.05]), 0.3 - 0.5)  # crossed and turned inwards
    fixed = planner.constrain(stance, crossing)
    local, yaw = stance.relative(fixed)
    assert local[1] == pytest.approx(planner.config.min_width) and local[0] == pytest.approx(0.1)
    assert yaw == pytest.approx(-planner.config.max_inward_yaw)


# --- step adapter --------------------------------------------------------------------------------
def _adapt(adapter, dcm, stance=Footstep("right", [0.0, -0.12]), offset=(0.0, 0.06), remaining=0.3, box=((-0.3, 0.4), (0.15, 0.45)), times=(0.1, 0.6), nominal=(0.2, 0.12)):
    return adapter.adapt(stance, stance.position, np.asarray(dcm), np.asarray(nominal), remaining, np.asarray(offset), box, times)


def test_step_adapter_lands_the_foot_on_the_dcm_offset_it_is_given():
    adapter = StepAdapter(OMEGA, StepAdapterWeights(position=1.0, timing=1.0, offset=1e4))
    stance = Footstep("right", [0.1, -0.12], 0.2)
    for dcm, offset in [((0.15, -0.03), (0.0, 0.06)), ((0.18, -0.04), (-0.05, 0.03)), ((0.12, 0.0), (0.02, -0.02))]:
        result = _adapt(adapter, dcm, stance=stance, offset=offset)
        # the predicted DCM at touch-down, from the closed form with the CoP on the stance sole
        predicted = dcm_at(result.remaining_time, np.asarray(dcm), stance.position, OMEGA)
        np.testing.assert_allclose(result.dcm_at_touchdown, predicted, atol=1e-12)
        np.testing.assert_allclose(result.position + np.asarray(offset), predicted, atol=2e-3)
        np.testing.assert_allclose(result.offset, offset, atol=2e-3)


def test_step_adapter_frame_made_once_per_step_gives_the_same_numbers(rng=np.random.default_rng(3)):
    """The walker makes the adapter's per-step part once (:meth:`StepAdapter.frame`) and adapts
    every tick with it: the same bits as :meth:`StepAdapter.adapt`, the lazily rotated DCM and
    offset included; a non-finite nominal step is refused when the frame is made."""
    adapter = StepAdapter(OMEGA)
    stance = Footstep("right", [0.1, -0.12], 0.3)
    nominal, offset, box = np.array([0.3, 0.1]), np.array([0.02, 0.05]), ((-0.3, 0.4), (0.15, 0.45))
    frame = StepFrame(stance, nominal, offset)
    for _ in range(20):
        dcm = stance.position + rng.normal(0.0, 0.1, 2)
        cop = stance.position + rng.normal(0.0, 0.02, 2)
        remaining = float(rng.uniform(0.05, 0.4))
        a = adapter.adapt(stance, cop, dcm, nominal, remaining, offset, box, (0.05, 0.5))
        b = adapter.adapt_in(frame, cop, dcm, remaining, box, (0.05, 0.5))
        assert a.remaining_time == b.remaining_time
        for x, y in ((a.position, b.position), (a.dcm_at_touchdown, b.dcm_at_touchdown), (a.offset, b.offset)):
            np.testing.assert_array_equal(x, y)
        # the predicted DCM: the LIPM closed form with the CoP held at `cop`
        np.testing.assert_allclose(b.dcm_at_touchdown, dcm_at(b.remaining_time, dcm, cop, OMEGA), atol=1e-12)
    with pytest.raises(ValueError, match="finite"):
        StepFrame(stance, np.array([math.nan, 0.0]), offset)
    with pytest.raises(ValueError, match="finite"):
        adapter.adapt_in(frame, stance.position, np.array([math.inf, 0.0]), 0.2, box, (0.05, 0.5))


def test_step_adapter_keeps_the_plan_when_the_dcm_is_on_plan():
    adapter = StepAdapter(OMEGA)
    stance = Footstep("right", [0.0, -0.12])
    nominal, remaining = np.array([0.2, 0.12]), 0.3
    offset = np.array([-0.03, -0.05])
    # the DCM the nominal plan expects now: it reaches nominal + offset after `remaining`
    on_plan = stance.position + (nominal + offset - stance.position) * math.exp(-OMEGA * remaining)
    result = _adapt(adapter, on_plan, stance=stance, offset=offset, remaining=remaining, nominal=nominal)
    np.testing.assert_allclose(result.position, nominal, atol=1e-9)
    assert result.remaining_time == pytest.approx(remaining, abs=1e-9)


def test_a_big_push_steps_sooner_when_the_landing_box_is_exhausted():
    adapter = StepAdapter(OMEGA)
    stance = Footstep("right", [0.0, -0.12])
    small = _adapt(adapter, (0.08, -0.08), stance=stance)
    big = _adapt(adapter, (0.25, -0.08), stance=stance)
    assert big.position[0] == pytest.approx(0.4)  # at the front of the box
    assert big.remaining_time < small.remaining_time  # and sooner
    assert big.remaining_time >= 0.1 - 1e-12



def test_the_dcm_shaper_gives_the_adapter_the_nominal_step_inside_its_deadband():
    """Estimated-DCM noise inside the deadband: the adapter sees the nominal DCM, so the plan is
    kept exactly; a push beyond it still moves the foot, by the error beyond the deadband."""
    adapter = StepAdapter(OMEGA)
    stance = Footstep("right", [0.0, -0.12])
    nominal, remaining, offset = np.array([0.2, 0.12]), 0.3, np.array([-0.03, -0.05])
    on_plan = stance.position + (nominal + offset - stance.position) * math.exp(-OMEGA * remaining)
    shaper = DcmErrorShaper(deadband=0.03)
    for noise in ([0.02, 0.0], [-0.01, 0.02], [0.0, -0.029]):
        seen = shaper(0.0, on_plan + np.array(noise), on_plan)
        np.testing.assert_array_equal(seen, on_plan)
        result = _adapt(adapter, seen, stance=stance, offset=offset, remaining=remaining, nominal=nominal)
        np.testing.assert_allclose(result.position, nominal, atol=1e-9)
    pushed = shaper(0.0, on_plan + np.array([0.08, 0.0]), on_plan)
    np.testing.assert_allclose(pushed, on_plan + np.array([0.05, 0.0]), atol=1e-12)
    moved = _adapt(adapter, pushed, stance=stance, offset=offset, remaining=remaining, nominal=nominal)
    assert moved.position[0] > nominal[0] + 0.05  # forward, by the grown error


def test_the_dcm_shaper_low_passes_the_error_and_forgets_it_at_reset():
    shaper = DcmErrorShaper(time_constant=0.02)
    nominal = np.zeros(2)
    assert shaper(0.0, np.array([0.1, 0.0]), nominal)[0] == pytest.approx(0.1)  # the first sample passes
    assert shaper(0.002, np.array([0.0, 0.0]), nominal)[0] == pytest.approx(0.1 * 0.02 / 0.022)  # one step of the filter
    shaper.reset()
    assert shaper(0.004, np.array([0.0, 0.0]), nominal)[0] == 0.0
    assert not DcmErrorShaper().active and DcmErrorShaper(0.01).active
    with pytest.raises(ValueError, match="deadband"):
        DcmErrorShaper(deadband=math.nan)


def test_the_dcm_shapers_deadband_fades_out_below_full_error():
    """With ``full_error`` the deadband still hides small errors, but a push's error reaches the
    adapter whole (the plain deadband kept taking 3 cm off it: a lateral push's step landed that much
    too narrow); in between the scale is linear and continuous at both ends."""
    nominal = np.array([0.1, -0.2])
    plain, fading = DcmErrorShaper(deadband=0.03), DcmErrorShaper(deadband=0.03, full_error=0.06)
    direction = np.array([0.6, -0.8])
    for size, expected in ((0.02, 0.0), (0.03, 0.0), (0.045, 0.03), (0.06, 0.06), (0.1, 0.1)):
        seen = fading(0.0, nominal + size * direction, nominal)
        np.testing.assert_allclose(seen, nominal + expected * direction, atol=1e-12)
    # the plain deadband on a 0.1 m error: 0.07 reaches the adapter
    np.testing.assert_allclose(plain(0.0, nominal + 0.1 * direction, nominal), nominal + 0.07 * direction, atol=1e-12)
    # without full_error: the plain deadband's formula, bit for bit
    for size in (0.01, 0.05, 0.08):
        error = (nominal + size * direction) - nominal
        np.testing.assert_array_equal(plain(0.0, nominal + size * direction, nominal), nominal + error * max(1.0 - 0.03 / float(np.linalg.norm(error)), 0.0))
    with pytest.raises(ValueError, match="full_error"):
        DcmErrorShaper(deadband=0.03, full_error=0.03)
    with pytest.raises(ValueError, match="adapt_full_error"):
        WalkerConfig(adapt_deadband=0.03, adapt_full_error=0.02)


def test_the_dcm_shapers_fade_comes_in_only_as_the_error_lasts():
    """With ``fade_delay`` a fresh error beyond the deadband gets the plain deadband; the fading's extra
    comes in linearly over that long an error (a push lasts) and restarts when the error drops inside
    the deadband or the step changes (an estimate's brief swing-end excursion gets the plain deadband)."""
    nominal, direction = np.array([0.1, -0.2]), np.array([0.6, -0.8])
    shaper = DcmErrorShaper(deadband=0.03, full_error=0.06, fade_delay=0.1)
    for t, size, expected in ((0.0, 0.045, 0.015), (0.05, 0.045, 0.0225), (0.1, 0.045, 0.03), (0.2, 0.045, 0.03),
                              (0.21, 0.02, 0.0), (0.22, 0.045, 0.015), (0.4, 0.07, 0.07)):  # fmt: skip
        np.testing.assert_allclose(shaper(t, nominal + size * direction, nominal), nominal + expected * direction, atol=1e-12)
    shaper.reset()
    np.testing.assert_allclose(shaper(0.5, nominal + 0.045 * direction, nominal), nominal + 0.015 * direction, atol=1e-12)
    with pytest.raises(ValueError, match="fade_delay"):
        DcmErrorShaper(deadband=0.03, full_error=0.06, fade_delay=-0.1)
    with pytest.raises(ValueError, match="adapt_fade_delay"):
        WalkerConfig(adapt_deadband=0.03, adapt_full_error=0.06, adapt_fade_delay=math.inf)
    with pytest.raises(ValueError, match="adapt_freeze_time"):
        WalkerConfig(adapt_freeze_time=-0.05)


def test_bounded_box_keeps_the_landing_within_the_bound_of_the_plan_and_inside_the_box():
    box = ((-0.3, 0.4), (0.15, 0.45))
    np.testing.assert_allclose(bounded_box(box, np.array([0.2, 0.25]), 0.1), ((0.1, 0.3), (0.15, 0.35)))
    assert bounded_box(box, np.array([0.2, 0.25]), math.inf) == box
    np.testing.assert_allclose(bounded_box(box, np.array([0.6, 0.25]), 0.1), ((0.3, 0.4), (0.15, 0.35)))  # plan outside: from the box's edge
    adapter = StepAdapter(OMEGA)
    big = _adapt(adapter, (0.25, -0.08), box=bounded_box(box, np.array([0.2, 0.12]), 0.1))
    assert big.position[0] == pytest.approx(0.3)  # the bound, not the box's front (0.4)

def test_box_qp_matches_a_brute_force_grid():
    rng = np.random.default_rng(7)
    for _ in range(20):
        m = rng.normal(size=(3, 3))
        H = m @ m.T + 0.1 * np.eye(3)
        g = rng.normal(size=3)
        lo, hi = -rng.uniform(0.1, 1.0, 3), rng.uniform(0.1, 1.0, 3)
        z = solve_box_qp(H, g, lo, hi)
        grid = np.stack(np.meshgrid(*[np.linspace(lo[i], hi[i], 41) for i in range(3)]), -1).reshape(-1, 3)
        costs = 0.5 * np.einsum("ij,jk,ik->i", grid, H, grid) + grid @ g
        assert 0.5 * z @ H @ z + g @ z <= costs.min() + 1e-12
        assert np.all(z >= lo - 1e-12) and np.all(z <= hi + 1e-12)


def test_the_fast_step_qp_matches_the_generic_box_qp():
    rng = np.random.default_rng(11)
    for _ in range(200):
        w_u, w_s, w_b = rng.uniform(0.1, 100.0, 3)
        u_nom, d, k = rng.normal(0, 0.2, 2), rng.normal(0, 0.2, 2), rng.normal(0, 0.2, 2)
        sigma_nom = rng.uniform(1.0, 6.0)
        lower = (rng.uniform(-0.4, 0.0), rng.uniform(-0.4, 0.0), rng.uniform(1.0, 2.0))
        upper = (rng.uniform(0.0, 0.4), rng.uniform(0.0, 0.4), rng.uniform(2.0, 8.0))
        H, g = step_qp_matrices(w_u, w_s, w_b, u_nom, sigma_nom, d, k)
        fast = solve_step_qp(w_u, w_s, w_b, u_nom, sigma_nom, d, k, lower, upper)
        generic = solve_box_qp(H, g, np.array(lower), np.array(upper))
        cost = lambda z: 0.5 * z @ H @ z + g @ z  # noqa: E731
        assert cost(fast) <= cost(generic) + 1e-9 * max(1.0, abs(cost(generic)))
        np.testing.assert_allclose(fast, generic, atol=1e-6)


# --- swing ---------------------------------------------------------------------------------------
def _sample(swing, t0, t1, n=4001):
    times = np.linspace(t0, t1, n)
    values = [swing.evaluate(t) for t in times]
    return times, np.array([v[0] for v in values]), np.array([v[1] for v in values]), np.array([v[2] for v in values])


def test_swing_is_continuous_reaches_its_apex_and_rests_at_both_ends():
    start, target = np.array([0.0, 0.12, 0.0, 0.0]), np.array([0.3, 0.14, 0.0, 0.2])
    swing = SwingTrajectory(1.0, 1.4, start, target, apex=0.08)
    times, p, v, a = _sample(swing, 0.9, 1.5)
    dt = times[1] - times[0]
    np.testing.assert_allclose(np.gradient(p, dt, axis=0)[5:-5], v[5:-5], atol=2e-3)  # v is p's derivative
    assert np.abs(np.diff(p, axis=0)).max() < 1e-3 and np.abs(np.diff(v, axis=0)).max() < 0.02  # no jumps
    np.testing.assert_allclose(swing.evaluate(1.0)[0], start)
    np.testing.assert_allclose(swing.evaluate(1.4)[0], target, atol=1e-12)
    for t in (1.0, 1.4):
        np.testing.assert_allclose(swing.evaluate(t)[1], 0.0, atol=1e-12)  # at rest at lift-off and touch-down
        np.testing.assert_allclose(swing.evaluate(t)[2], 0.0, atol=1e-9)
    assert p[:, 2].max() == pytest.approx(0.08, abs=1e-6) and swing.evaluate(1.2)[0][2] == pytest.approx(0.08)
    assert p[:, 2].min() >= -1e-12  # never below the ground


@pytest.mark.parametrize("when", [1.05, 1.25, 1.35])
def test_retargeting_in_flight_keeps_continuity_and_lands_at_rest_on_the_new_spot(when):
    start, target = np.array([0.0, 0.12, 0.0, 0.0]), np.array([0.3, 0.14, 0.0, 0.0])
    swing = SwingTrajectory(1.0, 1.4, start, target, apex=0.08)
    before = swing.evaluate(when)
    new_target, touchdown = np.array([0.4, 0.2, 0.0, 0.1]), max(1.32, when + 0.08)
    swing.retarget(when, new_target, touchdown)
    after = swing.evaluate(when)
    for x, y in zip(before, after):
        np.testing.assert_allclose(x, y, atol=1e-9)  # position, velocity, acceleration continuous
    times, p, v, _ = _sample(swing, when, touchdown + 0.05)
    assert np.abs(np.diff(v, axis=0)).max() < 0.1
    np.testing.assert_allclose(swing.evaluate(touchdown)[0], new_target, atol=1e-9)
    np.testing.assert_allclose(swing.evaluate(touchdown)[1], 0.0, atol=1e-9)
    assert swing.t1 == pytest.approx(touchdown)


def test_quintic_meets_its_end_conditions_and_the_swing_state_is_its_evaluation():
    """A quintic (the swing's pieces) takes the given position, velocity and acceleration at both
    ends; :meth:`SwingTrajectory.state` (floats, the walker's every-tick read) is
    :meth:`SwingTrajectory.evaluate`'s numbers, before and after a re-target."""
    start, end = (0.1, -0.4, 2.0), (0.35, 0.2, -1.0)
    c = quintic(1.0, 1.3, start, end)
    for s, expected in ((0.0, start), (0.3, end)):
        p = np.polyval(c[::-1], s)
        v = np.polyval(np.polyder(c[::-1]), s)
        a = np.polyval(np.polyder(c[::-1], 2), s)
        np.testing.assert_allclose([p, v, a], expected, atol=1e-9)
    with pytest.raises(ValueError):
        quintic(1.0, 1.0, start, end)
    swing = SwingTrajectory(1.0, 1.4, np.array([0.0, 0.12, 0.0, 0.0]), np.array([0.3, 0.14, 0.0, 0.2]), apex=0.08)
    for retarget in (False, True):
        if retarget:
            swing.retarget(1.1, np.array([0.35, 0.2, 0.0, 0.1]), 1.45)
        for t in (0.9, 1.05, 1.2, 1.38, 1.5):
            state = np.array(swing.state(t))  # (x, y, z, yaw) × (position, velocity, acceleration)
            for k, array in enumerate(swing.evaluate(t)):
                np.testing.assert_array_equal(state[:, k], array)


def test_swing_refuses_bad_input():
    with pytest.raises(ValueError):
        SwingTrajectory(1.0, 1.0, np.zeros(4), np.ones(4))
    with pytest.raises(ValueError):
        SwingTrajectory(0.0, 1.0, np.zeros(4), np.array([math.nan, 0, 0, 0]))


def test_the_locomotion_layer_imports_only_the_controller_and_robot_layers():
    """Beneath the tasks, above the WBC: giwbc.control, giwbc.plants (the simulated plant), giwbc.robot and giwbc.util
    (the compiled kernels' decorator) only (never tasks, runtimes or apps)."""
    import ast
    import pathlib

    import giwbc.locomotion

    allowed = ("giwbc.locomotion", "giwbc.control", "giwbc.plants", "giwbc.robot", "giwbc.util")
    for path in pathlib.Path(giwbc.locomotion.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            for name in names:
                if name.startswith("giwbc"):
                    assert name.startswith(allowed), f"{path.name} imports {name}"


@pytest.mark.parametrize("field", ["landing_box", "recovery_landing_box"])
@pytest.mark.parametrize("box", [((0.3, -0.3), (0.17, 0.6)), ((-0.3, 0.3), (0.0, 0.6)), ((-0.3, 0.3), (0.6, 0.2)), ((-0.3, math.nan), (0.17, 0.6))])
def test_walker_config_refuses_an_empty_or_crossing_landing_box(field, box):
    """A landing box must be non-empty and keep the foot on its own side (no crossing)."""
    with pytest.raises(ValueError, match=field):
        WalkerConfig(**{field: box})
