"""The orientation filter's building blocks against rotations computed another way (rotation
matrices): the error between two orientations, a tilt from a gravity direction, and gyro-only
propagation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.estimation.orientation import OrientationFilter, quaternion_error, tilt_from_gravity
from giwbc.robot import so3


def test_quaternion_error_is_the_small_body_rotation_between_two_orientations(rng) -> None:
    """From q to q turned by a small body-frame rotation r, the error is r (to second order),
    whichever sign the measured quaternion comes with."""
    for _ in range(20):
        q = so3.matrix_to_quat(so3.exp(rng.uniform(-math.pi, math.pi, 3)))
        r = rng.normal(0.0, 0.01, 3)
        measured = so3.matrix_to_quat(np.reshape(so3.quat_to_matrix_floats(q), (3, 3)) @ so3.exp(r))
        np.testing.assert_allclose(quaternion_error(q, measured), r, atol=1e-5)
        np.testing.assert_allclose(quaternion_error(q, -measured), r, atol=1e-5)


def test_tilt_from_gravity_is_a_rotation_whose_vertical_is_the_measured_up(rng) -> None:
    """Rows of the rotation are the world axes in the body frame: orthonormal, right-handed, the
    last one along ``up``; ``yaw`` turns the heading about the vertical (also for ``up`` along x,
    where the body x axis cannot give the heading)."""
    ups = [rng.normal(size=3) for _ in range(20)] + [np.array([1.0, 0.0, 0.0]), np.array([-2.0, 0.0, 0.0]), np.array([0.0, 0.0, 9.8])]
    for up in ups:
        for yaw in (0.0, 0.7):
            rotation = tilt_from_gravity(up, yaw)
            np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
            assert np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-12)
            np.testing.assert_allclose(rotation[2], up / np.linalg.norm(up), atol=1e-12)
        turned = tilt_from_gravity(up, 0.7) @ tilt_from_gravity(up, 0.0).T  # world-frame turn between the two
        np.testing.assert_allclose(turned, so3.exp(np.array([0.0, 0.0, 0.7])), atol=1e-12)


def test_without_a_reference_only_the_gyro_turns_the_orientation() -> None:
    """No orientation output and no accelerometer: the orientation follows the gyro alone (a
    still gyro keeps it; 0.5 rad/s about z for 1 s turns it 0.5 rad about z), with no pull."""
    f = OrientationFilter()
    f.reset_to((0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0))
    f.update((0.0, 0.0, 0.0), 0.01, (0.0, 0.0, 0.0, 1.0), None)  # a correction pending from an earlier reference
    for _ in range(100):
        f.update((0.0, 0.0, 0.0), 0.01, None, None)
    np.testing.assert_allclose(f.quaternion, [0.0, 0.0, 0.0, 1.0], atol=1e-12)
    for _ in range(100):
        f.update((0.0, 0.0, 0.5), 0.01, None, None)
    np.testing.assert_allclose(f.rotation, so3.exp(np.array([0.0, 0.0, 0.5])), atol=1e-9)


def test_gravity_error_is_zero_when_the_accelerometer_agrees_with_the_orientation(rng) -> None:
    """At rest the accelerometer reads gravity's reaction, R^T (0, 0, g) in the IMU frame: an
    orientation that explains it has no tilt error; one tilted by a small r about a horizontal body
    axis has an error of -r about it (to first order)."""
    from giwbc.estimation.orientation import gravity_error

    for _ in range(20):
        rotation = so3.exp(rng.uniform(-1.0, 1.0, 3))
        q = so3.matrix_to_quat(rotation)
        accel = rotation.T @ np.array([0.0, 0.0, 9.81])
        np.testing.assert_allclose(gravity_error(q, accel), 0.0, atol=1e-9)


def test_one_large_gyro_step_turns_by_its_whole_angle() -> None:
    """A single propagation over 0.5 s at 1.2 rad/s turns 0.6 rad (no small-angle series)."""
    f = OrientationFilter(orientation_gain=0.0, accel_gain=0.0)
    f.reset_to((0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0))
    f.propagate((1.2, 0.0, 0.0), 0.5)
    np.testing.assert_allclose(f.rotation, so3.exp(np.array([0.6, 0.0, 0.0])), atol=1e-12)


def test_a_quaternion_that_is_not_unit_is_normalized_on_reset() -> None:
    f = OrientationFilter()
    f.reset_to((0.0, 0.0, 2.0, 2.0), (0.0, 0.0, 0.0))
    np.testing.assert_allclose(f.quaternion, [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-15)


def test_quaternion_error_takes_the_short_way_across_half_a_turn() -> None:
    """From a heading of +168 degrees to one of -168 degrees the turn is +24 degrees, not -336: the
    error's sign follows the shorter rotation even where both quaternions' scalar parts are small."""
    q = so3.matrix_to_quat(so3.exp(np.array([0.0, 0.0, math.radians(168.0)])))
    measured = so3.matrix_to_quat(so3.exp(np.array([0.0, 0.0, math.radians(-168.0)])))
    error = quaternion_error(q, measured)
    np.testing.assert_allclose(error, [0.0, 0.0, 2.0 * math.sin(math.radians(12.0))], atol=1e-12)
    half = so3.matrix_to_quat(so3.exp(np.array([0.0, 0.0, math.pi / 2])))  # a quarter turn from a half turn
    turned = so3.matrix_to_quat(so3.exp(np.array([0.0, 0.0, math.pi])))  # scalar part 0
    np.testing.assert_allclose(quaternion_error(half, turned), [0.0, 0.0, 2.0 * math.sin(math.pi / 4)], atol=1e-12)


def test_a_new_filter_believes_no_gyro_bias_and_a_zero_gain_reference_changes_nothing() -> None:
    """Before any calibration the gyro is taken as it reads (a still gyro keeps the orientation); a
    reference given with gain 0 is switched off: it neither turns the estimate nor learns a bias."""
    filt = OrientationFilter()
    np.testing.assert_array_equal(filt.gyro_bias, np.zeros(3))
    for _ in range(100):
        filt.propagate((0.0, 0.0, 0.0), 0.01)
    np.testing.assert_allclose(filt.quaternion, [0.0, 0.0, 0.0, 1.0], atol=1e-15)
    off = OrientationFilter(bias_gain=0.2)
    off.reset_to((0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0))
    for _ in range(100):
        off.correct((0.01, -0.01, 0.01), 0.0, 0.2, 0.01)  # a 1-degree error, integral gain 0.2, gain 0
        off.propagate((0.0, 0.0, 0.0), 0.01)
    np.testing.assert_array_equal(off.gyro_bias, np.zeros(3))
    np.testing.assert_allclose(off.quaternion, [0.0, 0.0, 0.0, 1.0], atol=1e-15)


def test_propagation_from_any_orientation_matches_the_rotation_matrices(rng) -> None:
    """A constant body rate about a random axis, from a random orientation: after 1 s the filter's
    orientation is R0 exp(w t), computed with rotation matrices."""
    for _ in range(5):
        start = so3.exp(rng.uniform(-math.pi, math.pi, 3))
        rate = rng.normal(0.0, 0.5, 3)
        filt = OrientationFilter()
        filt.reset_to(so3.matrix_to_quat(start), (0.0, 0.0, 0.0))
        for _ in range(100):
            filt.propagate(rate, 0.01)
        np.testing.assert_allclose(filt.rotation, start @ so3.exp(rate * 1.0), atol=1e-9)


def test_initialize_from_gravity_alone_starts_level_and_refuses_free_fall() -> None:
    """Without an orientation output, a specific force of 1 g (at rest) gives the tilt, heading 0;
    one under half a g (falling) cannot."""
    filt = OrientationFilter()
    up = so3.exp(np.array([0.1, -0.2, 0.0])).T @ np.array([0.0, 0.0, 9.81])  # a base rolled and pitched, IMU frame
    assert filt.initialize(None, up)
    np.testing.assert_allclose(filt.rotation.T @ np.array([0.0, 0.0, 1.0]), up / 9.81, atol=1e-12)
    assert not OrientationFilter().initialize(None, np.array([0.0, 0.0, 3.0]))
