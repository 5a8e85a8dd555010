"""LIPM / DCM closed forms against numerical integration of the pendulum, the DCM reference
against the footstep planner, the DCM controller's error decay, support polygons."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.locomotion.dcm import CopSegment, DcmController, DcmReference, walking_cop_plan
from giwbc.locomotion.footsteps import Footstep, FootstepPlanner, GaitConfig, VelocityCommand
from giwbc.locomotion.lipm import (
    capture_point,
    com_at,
    dcm,
    dcm_at,
    dcm_at_linear_cop,
    dcm_before,
    dcm_before_linear_cop,
    natural_frequency,
)
from giwbc.locomotion.support import clip_to_polygon, convex_hull, signed_distance, sole_corners

OMEGA = natural_frequency(0.68)


def integrate_lipm(com, velocity, cop_of_t, omega, seconds, dt=1e-4):
    """RK4 on c̈ = ω² (c − p(t)); returns the final CoM and velocity."""
    c, v = np.array(com, dtype=float), np.array(velocity, dtype=float)
    t = 0.0
    for _ in range(int(round(seconds / dt))):
        def f(tt, cc, vv):
            return vv, omega**2 * (cc - cop_of_t(tt))
        k1 = f(t, c, v)
        k2 = f(t + dt / 2, c + dt / 2 * k1[0], v + dt / 2 * k1[1])
        k3 = f(t + dt / 2, c + dt / 2 * k2[0], v + dt / 2 * k2[1])
        k4 = f(t + dt, c + dt * k3[0], v + dt * k3[1])
        c = c + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v = v + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        t += dt
    return c, v


def test_natural_frequency_and_bad_heights():
    assert OMEGA == pytest.approx(math.sqrt(9.81 / 0.68))
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            natural_frequency(bad)


def test_dcm_diverges_from_the_cop_as_the_closed_form_says():
    com, velocity, cop = np.array([0.02, -0.01]), np.array([0.3, 0.1]), np.array([0.0, 0.0])
    xi0 = dcm(com, velocity, OMEGA)
    for t in (0.1, 0.35, 0.7):
        c, v = integrate_lipm(com, velocity, lambda _: cop, OMEGA, t)
        np.testing.assert_allclose(dcm(c, v, OMEGA), dcm_at(t, xi0, cop, OMEGA), atol=1e-9)
        c_closed, v_closed = com_at(t, com, velocity, cop, OMEGA)
        np.testing.assert_allclose(c, c_closed, atol=1e-9)
        np.testing.assert_allclose(v, v_closed, atol=1e-9)
    # the error from the CoP grows by e^{ωt}
    np.testing.assert_allclose(dcm_at(1.0, xi0, cop, OMEGA) - cop, (xi0 - cop) * math.exp(OMEGA), rtol=1e-12)
    np.testing.assert_allclose(dcm_before(0.4, dcm_at(0.4, xi0, cop, OMEGA), cop, OMEGA), xi0, atol=1e-12)


def test_cop_on_the_capture_point_brings_the_pendulum_to_rest_there():
    com, velocity = np.array([0.0, 0.0]), np.array([0.6, -0.2])  # a 20 N·s push on 33 kg
    point = capture_point(com, velocity, OMEGA)
    c, v = integrate_lipm(com, velocity, lambda _: point, OMEGA, 3.0)
    np.testing.assert_allclose(c, point, atol=1e-4)
    assert np.linalg.norm(v) < 1e-3
    # Anywhere else, it runs away.
    c, v = integrate_lipm(com, velocity, lambda _: point - [0.02, 0.0], OMEGA, 3.0)
    assert np.linalg.norm(c - point) > 0.5


def test_linear_cop_closed_form_matches_integration():
    p0, p1, T = np.array([0.0, 0.1]), np.array([0.2, -0.1]), 0.2
    xi0 = np.array([0.05, 0.08])
    com = xi0 - np.array([0.1, 0.0]) / OMEGA
    velocity = np.array([0.1, 0.0])
    xi0 = dcm(com, velocity, OMEGA)
    c, v = integrate_lipm(com, velocity, lambda t: p0 + (p1 - p0) * min(t, T) / T, OMEGA, T)
    xi, rate = dcm_at_linear_cop(T, T, xi0, p0, p1, OMEGA)
    np.testing.assert_allclose(dcm(c, v, OMEGA), xi, atol=1e-9)
    np.testing.assert_allclose(rate, OMEGA * (xi - p1), atol=1e-12)
    np.testing.assert_allclose(dcm_before_linear_cop(T, xi, p0, p1, OMEGA), xi0, atol=1e-12)


def _planned_reference(command, n=6):
    gait = GaitConfig()
    planner = FootstepPlanner(gait)
    stance = Footstep("left", [0.0, 0.12])
    steps, notes = planner.plan(stance, command, n)
    assert not notes
    final = 0.5 * (steps[-1].position + steps[-2].position)
    segments = walking_cop_plan(CopSegment(gait.single_support, stance.position, stance.position), [s.position for s in steps], gait.single_support, gait.double_support, final)
    return DcmReference(segments, OMEGA), steps, gait


def test_dcm_reference_through_planned_footsteps_is_a_lipm_solution_ending_at_rest():
    reference, steps, gait = _planned_reference(VelocityCommand(0.4, 0.0, 0.0))
    times = np.linspace(0.0, reference.end_time + 0.5, 2001)
    values = [reference.evaluate(t) for t in times]
    xi = np.array([v[0] for v in values])
    rate = np.array([v[1] for v in values])
    cop = np.array([v[2] for v in values])
    np.testing.assert_allclose(rate, OMEGA * (xi - cop), atol=1e-9)  # ξ̇ = ω (ξ − p) everywhere
    assert np.abs(np.diff(xi, axis=0)).max() < 0.01  # continuous (no jump at segment boundaries)
    np.testing.assert_allclose(xi[-1], 0.5 * (steps[-1].position + steps[-2].position), atol=1e-12)
    # Driving the pendulum with the planned CoP from the planned DCM follows the plan (open loop).
    xi0 = reference.evaluate(0.0)[0]
    com0 = xi0.copy()  # at rest relative to... ċ = ω (ξ − c) = 0
    c, v = integrate_lipm(com0, np.zeros(2), lambda t: reference.evaluate(t)[2], OMEGA, 1.5, dt=5e-4)
    np.testing.assert_allclose(dcm(c, v, OMEGA), reference.evaluate(1.5)[0], atol=2e-3)
    # It moves forward at the commanded speed while walking (DCM at two step starts).
    period = gait.step_period
    advance = reference.evaluate(4 * period)[0][0] - reference.evaluate(2 * period)[0][0]
    assert advance / (2 * period) == pytest.approx(0.4, rel=0.05)


def test_dcm_controller_error_decays_at_its_gain():
    reference, _, _ = _planned_reference(VelocityCommand(0.3, 0.0, 0.0))
    controller = DcmController(OMEGA, gain=3.0)
    xi_ref0 = reference.evaluate(0.0)[0]
    error0 = np.array([0.03, -0.02])
    c, v = xi_ref0 + error0, np.zeros(2)
    dt, t = 5e-4, 0.0
    while t < 1.0 - 1e-12:  # semi-implicit Euler on the LIPM with the commanded CoP
        xi_ref, rate_ref, _ = reference.evaluate(t)
        cop = controller.desired_cop(dcm(c, v, OMEGA), xi_ref, rate_ref)
        a = controller.com_acceleration(c, cop)
        v = v + dt * a
        c = c + dt * v
        t += dt
    error = dcm(c, v, OMEGA) - reference.evaluate(t)[0]
    np.testing.assert_allclose(error, error0 * math.exp(-3.0 * 1.0), atol=2e-3)


def test_support_polygon_of_two_feet_inside_outside_and_clip():
    hull = convex_hull(np.vstack([sole_corners([0.0, 0.12], 0.0, 0.085, 0.03), sole_corners([0.0, -0.12], 0.0, 0.085, 0.03)]))
    assert len(hull) == 4
    assert signed_distance([0.0, 0.0], hull) == pytest.approx(-0.085)
    assert signed_distance([0.2, 0.0], hull) == pytest.approx(0.115)
    np.testing.assert_allclose(clip_to_polygon([0.2, 0.0], hull), [0.085, 0.0])
    np.testing.assert_allclose(clip_to_polygon([0.01, 0.02], hull), [0.01, 0.02])
    np.testing.assert_allclose(clip_to_polygon([0.3, 0.4], hull), [0.085, 0.15])
    yawed = convex_hull(sole_corners([1.0, 0.0], math.pi / 2, 0.1, 0.03))
    assert signed_distance([1.0, 0.09], yawed) < 0 and signed_distance([1.05, 0.0], yawed) > 0


def test_dcm_reference_refuses_bad_segments():
    with pytest.raises(ValueError):
        DcmReference([], OMEGA)
    with pytest.raises(ValueError):
        DcmReference([CopSegment(0.0, np.zeros(2), np.zeros(2))], OMEGA)
    with pytest.raises(ValueError):
        DcmController(OMEGA, gain=math.nan)


def test_a_reference_put_before_a_plan_is_the_reference_of_the_whole_plan(rng):
    """``DcmReference.before`` reuses the plan's backward pass: the same numbers, bit for bit, as
    the reference of the whole CoP plan (a double support's ramp in front of the walk)."""

    omega = 3.3
    stance = rng.normal(0.0, 0.1, 2)
    landings = [stance + np.array([0.15 * (i + 1), 0.2 * (-1) ** i]) for i in range(3)]
    rest = walking_cop_plan(CopSegment(0.4, stance, stance), landings, 0.4, 0.15, 0.5 * (landings[-1] + landings[-2]))
    tail = DcmReference(rest, omega)
    ramp = CopSegment(0.13, rng.normal(0.0, 0.05, 2), stance)
    joined, whole = DcmReference.before(ramp, tail, 2.5), DcmReference([ramp, *rest], omega, 2.5)
    np.testing.assert_array_equal(joined.initial, whole.initial)
    np.testing.assert_array_equal(joined.starts, whole.starts)
    assert joined.end_time == whole.end_time
    np.testing.assert_array_equal(joined.initial[1], tail.initial[0])
    for t in np.linspace(2.4, whole.end_time + 0.1, 37):
        for a, b in zip(joined.evaluate(t), whole.evaluate(t)):
            np.testing.assert_array_equal(a, b)
