"""The safety supervisor's checks at their edges: thresholds exactly met (not a fault) and just
passed (a fault), counters that must restart, what each fault says (the operator reads the joint,
the value and the limit), the config's validation, the reset, and the signal watch's restore."""

from __future__ import annotations

import gc
import json
import math
import os
import signal
import threading
import warnings

import numpy as np
import pytest

from giwbc.hal.can_robot import CycleReport
from giwbc.hal.safety import Fault, FaultKind, SafetyConfig, SafetySupervisor, SignalWatch, damping_command
from giwbc.robot import so3
from giwbc.robot.interface import ImuReading

DT = 0.002
CONFIG = SafetyConfig()
LEVEL = ImuReading(np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.array([0.0, 0.0, 9.81]))


def report(g1, cycle: int = 0, **fields) -> CycleReport:
    n = g1.dofs
    base = dict(cycle=cycle, time=cycle * DT, kind="command", missing=np.zeros(n, bool), stale=np.zeros(n, np.int64),
                error_code=np.zeros(n, np.int64), temperature=np.full(n, 30.0), late=0, corrupt=np.zeros(2, np.int64),
                unknown=0, send_dropped=0, clamped=0, imu_fresh=True, send_s=0.0, receive_s=0.0)  # fmt: skip
    base.update(fields)
    return CycleReport(**base)


class Checker:
    """A supervisor fed one cycle at a time (the cycle counter advances by itself)."""

    def __init__(self, g1, config: SafetyConfig = CONFIG, **kwargs) -> None:
        self.g1, self.sup, self.cycle = g1, SafetySupervisor(g1, config, **kwargs), 0
        self.q, self.zeros = g1.default_positions.copy(), np.zeros(g1.dofs)

    def __call__(self, q=None, dq=None, tau=None, imu=LEVEL, **fields) -> list[Fault]:
        faults = self.sup.check(report(self.g1, self.cycle, **fields), self.q if q is None else q,
                                self.zeros if dq is None else dq, self.zeros if tau is None else tau, imu)  # fmt: skip
        self.cycle += 1
        return faults


def joint(g1, name: str) -> int:
    return g1.joint_names.index(name)


# --- configuration -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["max_missing_cycles", "max_corrupt_frames", "corrupt_window", "torque_cycles", "imu_timeout_cycles"])
def test_every_cycle_count_must_be_at_least_one(name: str) -> None:
    with pytest.raises(ValueError, match=f"safety {name} must be >= 1"):
        SafetyConfig(**{name: 0})
    assert getattr(SafetyConfig(**{name: 1}), name) == 1


def test_tilt_and_damping_settings_are_validated() -> None:
    message = "safety max_tilt and gravity_tilt_gain must be > 0, damping_time and damping_kd_scale >= 0"
    for bad in ({"max_tilt": 0.0}, {"damping_time": -0.1}, {"damping_kd_scale": -1.0}, {"max_tilt": -1.0, "damping_time": 1.0},
                {"gravity_tilt_gain": 0.0}):  # fmt: skip
        with pytest.raises(ValueError) as raised:
            SafetyConfig(**bad)
        assert str(raised.value) == message
    config = SafetyConfig(max_tilt=0.3, damping_time=0.0, damping_kd_scale=0.0)  # edges that are allowed
    assert (config.max_tilt, config.damping_time, config.damping_kd_scale) == (0.3, 0.0, 0.0)


def test_the_stop_margin_must_be_positive() -> None:
    """The watchdog's allowance past a safe stop's nominal length: zero would stop a stop that is
    exactly on time."""
    for bad in (0.0, -1.0):
        with pytest.raises(ValueError) as raised:
            SafetyConfig(stop_margin=bad)
        assert str(raised.value) == f"safety stop_margin must be > 0, got {bad}"
    assert SafetyConfig(stop_margin=1e-3).stop_margin == 1e-3


def test_damping_command_is_pure_damping(g1) -> None:
    command = damping_command(g1, SafetyConfig(damping_kd_scale=0.5))
    np.testing.assert_array_equal(command.kp, 0.0)
    np.testing.assert_allclose(command.kd, 0.5 * g1.kd)
    np.testing.assert_array_equal(command.tau_ff, 0.0)
    assert command.kd.shape == (g1.dofs,)


def test_fault_as_dict_is_the_logged_record() -> None:
    fault = Fault(FaultKind.FALL, "tilted", 12, 0.024, ("a", "b"))
    record = fault.as_dict()
    assert record == {"kind": "fall", "message": "tilted", "cycle": 12, "time": 0.024, "joints": ["a", "b"]}
    assert json.loads(json.dumps(record)) == record
    assert str(fault) == "fall at cycle 12 (t = 0.024 s): tilted"


# --- motor reports -----------------------------------------------------------------------------
def test_motor_error_codes_name_the_joint_and_the_code(g1) -> None:
    check = Checker(g1)
    codes = np.zeros(g1.dofs, np.int64)
    codes[3] = -1  # not reported by the variant: never a fault
    assert check(error_code=codes) == []
    codes[5] = 1
    (fault,) = check(error_code=codes)
    assert fault.kind is FaultKind.MOTOR_ERROR and fault.joints == (g1.joint_names[5],)
    assert fault.message == f"motor error code(s): {g1.joint_names[5]}=1"
    assert (fault.cycle, fault.time) == (1, 1 * DT)
    codes[7] = 11
    (fault,) = check(error_code=codes)
    assert fault.message == f"motor error code(s): {g1.joint_names[5]}=1, {g1.joint_names[7]}=11"


def test_over_temperature_starts_above_the_limit(g1) -> None:
    check = Checker(g1)
    temperature = np.full(g1.dofs, 30.0)
    temperature[2] = CONFIG.max_temperature  # at the limit: still fine
    assert check(temperature=temperature) == []
    temperature[2] += 1.0
    temperature[4] = CONFIG.max_temperature + 5.0
    (fault,) = check(temperature=temperature)
    assert fault.kind is FaultKind.OVER_TEMPERATURE and fault.joints == (g1.joint_names[2], g1.joint_names[4])
    assert fault.message == f"above 80°C: {g1.joint_names[2]}=81°C, {g1.joint_names[4]}=85°C"


def test_corrupt_frames_count_within_a_sliding_window(g1) -> None:
    check = Checker(g1, bus_names=("can0", "can1"))
    one = np.array([0, 1], np.int64)
    quiet = np.zeros(2, np.int64)
    # One corrupt frame every 30 cycles: never three within 50 cycles (old ones leave the window).
    for c in range(200):
        assert check(corrupt=one if c % 30 == 0 else quiet) == [], c
    for _ in range(50):
        assert check(corrupt=quiet) == []
    # Two at once and one more within the window: a fault naming the bus and its count.
    assert check(corrupt=np.array([0, 2], np.int64)) == []
    (fault,) = check(corrupt=one)
    assert fault.kind is FaultKind.CORRUPT_FRAMES and fault.joints == ()
    assert fault.message == "corrupt frames in the last 50 cycles on can1 (3)"


def test_missing_replies_name_the_silent_motors_and_late_frames(g1) -> None:
    check = Checker(g1)
    stale = np.zeros(g1.dofs, np.int64)
    stale[1] = CONFIG.max_missing_cycles - 1
    assert check(stale=stale) == []
    stale[1] = CONFIG.max_missing_cycles
    (fault,) = check(stale=stale)
    assert fault.message == f"no valid reply for >= 3 cycles: {g1.joint_names[1]} (3)"
    assert fault.joints == (g1.joint_names[1],)
    (fault,) = check(stale=stale, late=2)
    assert fault.message == f"no valid reply for >= 3 cycles: {g1.joint_names[1]} (3); 2 late frame(s) this cycle"


# --- IMU and tilt ------------------------------------------------------------------------------
def test_imu_timeout_counts_cycles_since_the_last_fresh_sample(g1) -> None:
    check = Checker(g1)
    assert check(imu_fresh=True) == []
    for _ in range(CONFIG.imu_timeout_cycles - 1):  # 9 stale cycles after a fresh one: fine
        assert check(imu_fresh=False) == []
    (fault,) = check(imu_fresh=False)
    assert fault.kind is FaultKind.IMU and fault.message == "no fresh IMU sample for 10 cycles"
    assert check(imu_fresh=True) == []  # a fresh sample restarts the count
    assert check(imu=None) == []  # no sample at all counts as stale too ...
    for _ in range(CONFIG.imu_timeout_cycles - 2):
        assert check(imu_fresh=False) == []
    assert [f.kind for f in check(imu=None)] == [FaultKind.IMU]


def test_non_finite_imu_is_a_fault_with_the_sample(g1) -> None:
    bad = ImuReading(np.array([0.0, 0.0, 0.0, 1.0]), np.array([0.0, np.inf, 0.0]), np.zeros(3))
    (fault,) = Checker(g1)(imu=bad)
    assert fault.kind is FaultKind.IMU and fault.message.startswith("IMU sample is not finite")


def test_an_orientation_output_with_one_nan_entry_is_a_fault_not_an_imu_without_one(g1) -> None:
    """Only an all-NaN quaternion means "this IMU has no orientation output"; one NaN entry is a
    broken sample, whatever the gyro and accelerometer say."""
    for entry in range(4):
        quaternion = np.array([0.0, 0.0, 0.0, 1.0])
        quaternion[entry] = np.nan
        (fault,) = Checker(g1)(imu=ImuReading(quaternion, np.zeros(3), np.array([0.0, 0.0, 9.81])))
        assert fault.kind is FaultKind.IMU and fault.message.startswith("IMU sample is not finite")


def tilted(angle: float, axis=(1.0, 0.0, 0.0)) -> ImuReading:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    quaternion = np.concatenate([math.sin(angle / 2) * axis, [math.cos(angle / 2)]])
    return ImuReading(quaternion, np.zeros(3), np.zeros(3))


def test_fall_starts_beyond_the_tilt_limit_not_at_it(g1) -> None:
    imu = tilted(0.5, (1.0, 1.0, 0.0))
    tilt = SafetySupervisor(g1).base_tilt(imu)
    assert tilt == pytest.approx(0.5, abs=1e-12)
    assert Checker(g1, SafetyConfig(max_tilt=tilt))(imu=imu) == []  # exactly at the limit
    (fault,) = Checker(g1, SafetyConfig(max_tilt=tilt - 1e-6))(imu=imu)
    assert fault.kind is FaultKind.FALL and fault.message == "base tilt 28.6° beyond 28.6°" and fault.joints == ()


def test_base_tilt_is_the_angle_of_the_base_z_axis_from_vertical(g1, rng) -> None:
    sup = SafetySupervisor(g1)
    for _ in range(50):
        quaternion = rng.normal(size=4)
        quaternion /= np.linalg.norm(quaternion)
        x, y, z, w = quaternion
        world_z_of_imu = np.array([2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)])  # third column of R
        expected = math.acos(np.clip(world_z_of_imu[2], -1, 1))
        assert sup.base_tilt(ImuReading(quaternion, np.zeros(3), np.zeros(3))) == pytest.approx(expected, abs=1e-9)
    # Upside down, with a quaternion a hair off unit length: pi, not a math domain error.
    assert sup.base_tilt(ImuReading(np.array([1.0 + 1e-9, 0.0, 0.0, 0.0]), np.zeros(3), np.zeros(3))) == pytest.approx(math.pi)


# --- an IMU without orientation output ------------------------------------------------------------
NO_ORIENTATION = np.full(4, np.nan)


def _mems_sample(rotation: np.ndarray, omega: np.ndarray, t: float, rng, *, gyro_bias=np.zeros(3), force=None) -> ImuReading:
    """A gyro + accelerometer sample of a base at ``rotation`` (world) turning at ``omega`` (body):
    noise of a MEMS IMU; ``force``: the specific force in the body frame (default: gravity's)."""
    specific = rotation.T @ np.array([0.0, 0.0, 9.81]) if force is None else force
    return ImuReading(NO_ORIENTATION, omega + gyro_bias + 0.011 * rng.standard_normal(3),
                      specific + 0.045 * rng.standard_normal(3), t)  # fmt: skip


def test_without_orientation_output_a_biased_standing_imu_never_trips_and_a_tilt_is_read_from_gravity(g1, rng) -> None:
    """A standing robot with a cheap IMU (2 deg/s gyro bias on every axis, no orientation output):
    60 s without a fault, the tilt within a few degrees; then the same IMU held still at a tilt
    beyond the limit (a fault injected as a tilt): FALL."""
    checker = Checker(g1)
    bias = np.full(3, math.radians(2.0))
    tilts = []
    for k in range(int(60.0 / DT)):
        imu = _mems_sample(np.eye(3), np.zeros(3), k * DT, rng, gyro_bias=bias)
        assert checker(imu=imu) == []
        tilts.append(checker.sup.imu_tilt(imu))  # the same sample again: not taken twice
    assert max(tilts) < math.radians(5.0) and tilts[-1] < math.radians(0.5)  # the bias's lag (4.3 deg), then learnt
    assert [f.kind for f in checker(imu=ImuReading(NO_ORIENTATION, np.array([0.0, np.nan, 0.0]), np.zeros(3), 60.0))] == [FaultKind.IMU]
    tilted = so3.exp(np.array([CONFIG.max_tilt + 0.1, 0.0, 0.0]))
    checker.sup.reset()
    faults = [checker(imu=_mems_sample(tilted, np.zeros(3), 61.0 + k * DT, rng)) for k in range(10)]
    assert faults[0] and faults[0][0].kind is FaultKind.FALL and "beyond 40.1°" in faults[0][0].message


def test_without_orientation_output_a_fall_the_accelerometer_cannot_see_is_caught_by_the_gyro(g1, rng) -> None:
    """Tipping over the feet like a pendulum, the specific force stays along the body's z axis:
    gravity alone would read "level" all the way down. Tipping at 1 rad/s from level, the gyro
    path reports FALL before the base is 0.05 rad past the limit."""
    checker = Checker(g1)
    for k in range(int(2.0 / DT)):  # standing: the filter settles
        assert checker(imu=_mems_sample(np.eye(3), np.zeros(3), k * DT, rng)) == []
    rate = np.array([0.0, 1.0, 0.0])
    for k in range(int(1.5 / DT)):
        angle = k * DT * 1.0
        along_body = np.array([0.0, 0.0, 9.81 * math.cos(angle)])  # no tangential component: a pendulum's
        faults = checker(imu=_mems_sample(so3.exp(rate * angle), rate, 2.0 + k * DT, rng, force=along_body))
        if faults:
            break
    assert [f.kind for f in faults] == [FaultKind.FALL]
    assert CONFIG.max_tilt < angle < CONFIG.max_tilt + 0.05, angle  # caught 0.024 rad past the limit


@pytest.mark.parametrize("broken", ["gyro", "accel", "time"])
def test_without_orientation_output_one_broken_sample_is_one_fault_and_the_tilt_comes_back(g1, broken: str) -> None:
    """A non-finite gyro, accelerometer or timestamp is an IMU fault for that sample only: it is
    not taken into the tilt, so the next good samples read the robot level again."""
    checker = Checker(g1)
    level = np.array([0.0, 0.0, 9.81])
    for k in range(50):
        assert checker(imu=ImuReading(NO_ORIENTATION, np.zeros(3), level, k * DT)) == []
    gyro, accel, t = np.zeros(3), level.copy(), 50 * DT
    if broken == "gyro":
        gyro[1] = np.nan
    elif broken == "accel":
        accel[0] = np.nan
    else:
        t = math.nan
    assert [f.kind for f in checker(imu=ImuReading(NO_ORIENTATION, gyro, accel, t))] == [FaultKind.IMU]
    for k in range(51, 60):
        imu = ImuReading(NO_ORIENTATION, np.zeros(3), level, k * DT)
        assert checker(imu=imu) == []
        assert checker.sup.imu_tilt(imu) < 1e-6


def test_without_orientation_output_a_gap_in_the_samples_is_not_read_as_a_long_turn(g1) -> None:
    """After 2 s without an IMU sample, a sample turning at 1 rad/s is integrated over at most
    0.1 s (5.7 deg), not over the gap or a second: a dropped stream does not fake a fall."""
    checker = Checker(g1)
    level = np.array([0.0, 0.0, 9.81])
    for k in range(50):
        assert checker(imu=ImuReading(NO_ORIENTATION, np.zeros(3), level, k * DT)) == []
    imu = ImuReading(NO_ORIENTATION, np.array([1.0, 0.0, 0.0]), level, 50 * DT + 2.0)
    assert checker(imu=imu) == []
    assert checker.sup.imu_tilt(imu) == pytest.approx(0.1, abs=0.01)


def test_without_orientation_output_the_configured_gain_pulls_the_tilt_to_gravity(g1) -> None:
    """Held still at 0.3 rad (the accelerometer shows it, the gyro reads nothing), the tilt read
    from a level start follows gravity at ``gravity_tilt_gain``: after 1 s at 4 /s within 0.03 rad of
    it (the bias integral overshoots a little), at 0.5 /s near 0.3 (1 - e^-0.5) = 0.12 rad."""
    tilt = 0.3
    gravity = 9.81 * np.array([0.0, math.sin(tilt), math.cos(tilt)])  # the base turned about x by 0.3 rad
    for gain, low, high in ((4.0, 0.27, 0.33), (0.5, 0.09, 0.15)):
        checker = Checker(g1, SafetyConfig(gravity_tilt_gain=gain))
        checker(imu=ImuReading(NO_ORIENTATION, np.zeros(3), np.array([0.0, 0.0, 9.81]), 0.0))
        for k in range(1, 501):
            imu = ImuReading(NO_ORIENTATION, np.zeros(3), gravity, k * DT)
            checker(imu=imu)
        assert low < checker.sup.imu_tilt(imu) < high, gain


def test_a_rotated_imu_mount_measures_the_base_tilt(g1, monkeypatch, rng) -> None:
    """With the IMU mounted rotated in the base (R_bi), the tilt is the base's: R_wb = R_wi R_biᵀ."""
    from giwbc.robot import so3
    from giwbc.robot.interface import quat_to_matrix

    mount = so3.exp(np.array([0.6, -0.9, 1.3]))  # a mount with no axis aligned with the base's
    assert np.all(np.abs(mount.T[:, 2]) > 0.1)
    import pinocchio as pin

    g1.imu_in_base  # noqa: B018  (computed and cached, so that monkeypatch restores it afterwards)
    monkeypatch.setitem(g1.__dict__, "imu_in_base", pin.SE3(mount, np.zeros(3)))  # the description's mount
    sup = SafetySupervisor(g1)
    # Base level (the IMU's orientation is its mount), the quaternion a hair long: 0, not a domain error.
    level = so3.matrix_to_quat(mount) * (1 + 1e-9)
    assert sup.base_tilt(ImuReading(level, np.zeros(3), np.zeros(3))) == pytest.approx(0.0, abs=1e-4)

    for _ in range(30):
        quaternion = rng.normal(size=4)
        quaternion /= np.linalg.norm(quaternion)
        base = quat_to_matrix(quaternion) @ mount.T
        expected = math.acos(np.clip(base[2, 2], -1, 1))
        assert sup.base_tilt(ImuReading(quaternion, np.zeros(3), np.zeros(3))) == pytest.approx(expected, abs=1e-9)


def test_a_fixed_base_robot_is_supervised_with_its_imu_unrotated(cartpole) -> None:
    sup = SafetySupervisor(cartpole)
    assert sup.description is cartpole
    assert sup.base_tilt(tilted(0.2)) == pytest.approx(0.2)
    n = cartpole.dofs
    assert sup.check(report(cartpole, missing=np.zeros(n, bool), stale=np.zeros(n, np.int64), error_code=np.zeros(n, np.int64),
                            temperature=np.full(n, 30.0)), np.zeros(n), np.zeros(n), np.zeros(n), LEVEL) == []  # fmt: skip
    # The passive pivot has no effort limit (0): whatever torque it reads, never a torque fault.
    tau = np.array([0.0, 0.5])
    for c in range(5):
        assert sup.check(report(cartpole, c, missing=np.zeros(n, bool), stale=np.zeros(n, np.int64),
                                error_code=np.zeros(n, np.int64), temperature=np.full(n, 30.0)),
                         np.zeros(n), np.zeros(n), tau, LEVEL) == []  # fmt: skip


# --- joints ------------------------------------------------------------------------------------
def test_soft_limits_are_inclusive_at_both_ends(g1) -> None:
    check = Checker(g1)
    k = joint(g1, "left_knee_joint")
    lower, upper = g1.position_limits
    q = check.q.copy()
    assert check(q=q) == []  # armed: inside
    for edge in (lower[k] + CONFIG.soft_limit_margin, upper[k] - CONFIG.soft_limit_margin):
        q[k] = edge
        assert check(q=q) == [], edge  # on the soft limit: still inside
    q[k] = upper[k] - 0.5 * CONFIG.soft_limit_margin
    (fault,) = check(q=q)
    assert fault.kind is FaultKind.JOINT_LIMIT and fault.joints == ("left_knee_joint",)
    soft_lower, soft_upper = lower[k] + CONFIG.soft_limit_margin, upper[k] - CONFIG.soft_limit_margin
    assert fault.message == f"beyond soft limits: left_knee_joint={q[k]:.3f} not in [{soft_lower:.3f}, {soft_upper:.3f}]"
    missing = np.zeros(g1.dofs, bool)
    missing[k] = True
    assert check(q=q, missing=missing) == []  # a motor that did not answer is not judged on its stale position


def test_velocity_limit_is_inclusive_and_scaled(g1) -> None:
    k = joint(g1, "waist_yaw_joint")
    dq = np.zeros(g1.dofs)
    dq[k] = g1.velocity_limits[k]
    assert Checker(g1)(dq=dq) == []  # at the limit
    dq[k] = -1.5 * g1.velocity_limits[k]
    (fault,) = Checker(g1)(dq=dq)
    assert fault.kind is FaultKind.VELOCITY_LIMIT and fault.joints == ("waist_yaw_joint",)
    assert fault.message == f"beyond velocity limits: waist_yaw_joint={dq[k]:.1f} rad/s"
    assert Checker(g1, SafetyConfig(velocity_scale=2.0))(dq=dq) == []  # within twice the limit


def test_torque_limit_needs_consecutive_cycles_and_restarts_its_count(g1) -> None:
    check = Checker(g1)
    k = joint(g1, "left_knee_joint")
    tau = np.zeros(g1.dofs)
    tau[k] = CONFIG.torque_scale * g1.effort_limits[k]
    for _ in range(5):
        assert check(tau=tau) == []  # at the limit: never
    tau[k] *= 1.01
    for pattern in ([True, True, False, True, True], [True, True, False, True]):  # never three in a row
        for over in pattern:
            assert check(tau=tau if over else None) == []
        assert check() == []
    assert check(tau=tau) == [] and check(tau=tau) == []
    (fault,) = check(tau=tau)
    assert fault.kind is FaultKind.TORQUE_LIMIT and fault.joints == ("left_knee_joint",)
    assert fault.message == f"beyond torque limits for 3 cycles: left_knee_joint={tau[k]:.1f} N m"
    assert Checker(g1, SafetyConfig(torque_scale=2.0))(tau=tau) == []


def test_checks_are_counted(g1) -> None:
    check = Checker(g1)
    for _ in range(4):
        check()
    assert check.sup.checks == 4
    assert SafetySupervisor(g1).config == SafetyConfig()  # no config: the defaults
    assert SafetySupervisor(g1).bus_names == ("bus0",)  # one bus unless told
    assert SafetySupervisor(g1, n_buses=3).bus_names == ("bus0", "bus1", "bus2")


def test_reset_forgets_every_history(g1) -> None:
    check = Checker(g1, bus_names=("can0", "can1"))
    k = joint(g1, "left_knee_joint")
    lower, _ = g1.position_limits
    tau = np.zeros(g1.dofs)
    tau[k] = 2 * g1.effort_limits[k]
    check(tau=tau, corrupt=np.array([0, 2], np.int64))
    check(tau=tau, imu_fresh=False)
    for _ in range(CONFIG.imu_timeout_cycles - 3):
        check(imu_fresh=False)
    check.sup.reset()
    q = check.q.copy()
    q[k] = lower[k]  # on the hard stop: not armed again after the reset
    assert check(q=q, tau=tau, imu_fresh=False, corrupt=np.array([0, 1], np.int64)) == []
    assert check(q=q, imu_fresh=False) == []
    for _ in range(CONFIG.imu_timeout_cycles - 3):
        assert check(q=q, imu_fresh=False) == []


def test_after_a_reset_every_count_starts_from_zero(g1) -> None:
    check = Checker(g1, bus_names=("can0", "can1"))
    k = joint(g1, "left_knee_joint")
    tau = np.zeros(g1.dofs)
    tau[k] = 2 * g1.effort_limits[k]
    check(tau=tau, corrupt=np.array([0, 1], np.int64))
    check(tau=tau, corrupt=np.array([0, 1], np.int64))
    check.sup.reset()
    assert check(tau=tau, corrupt=np.array([0, 2], np.int64)) == []  # 1 cycle over, 2 corrupt frames
    assert check(tau=tau) == []  # 2 cycles over
    kinds = [f.kind for f in check(tau=tau, corrupt=np.array([0, 1], np.int64))]  # the third of each
    assert kinds == [FaultKind.CORRUPT_FRAMES, FaultKind.TORQUE_LIMIT]


def test_after_a_reset_a_bus_needs_every_bus_off_cycle_again(g1) -> None:
    """Bus-off needs ``bus_off_cycles`` (2) consecutive cycles in which the driver refused every
    frame; a reset forgets the cycles counted before it."""
    check = Checker(g1, bus_names=("can0", "can1"))
    sent, errors = np.array([5, 0]), np.array([0, 5])
    refused = dict(bus_sent=sent, bus_errors=errors, driver_errors=(None, OSError("No buffer space available")))
    assert check(**refused) == []
    check.sup.reset()
    assert check(**refused) == []  # the first cycle again
    (fault,) = check(**refused)
    assert fault.kind is FaultKind.BUS_OFF and "for 2 cycles on can1 (OSError: No buffer space available)" in fault.message


def test_bus_off_needs_consecutive_cycles_of_every_frame_refused(g1) -> None:
    """A bus is refused when its driver raised and took no frame; an idle bus (nothing sent, no
    error) or one that still took frames is not. One good cycle, even a quiet one, restarts the
    count; the cause is optional and the message names each bus-off bus."""
    check = Checker(g1, bus_names=("can0", "can1", "can2"))
    quiet = dict(bus_sent=np.array([4, 4, 4]), bus_errors=np.zeros(3, np.int64), driver_errors=(None, None, None))
    one_refused = dict(bus_sent=np.array([4, 0, 4]), bus_errors=np.array([0, 1, 0]), driver_errors=())
    assert check(**quiet) == []
    for _ in range(3):  # can0 idle, can1 raising but taking frames, can2 fine
        assert check(bus_sent=np.array([0, 3, 4]), bus_errors=np.array([0, 2, 0]), driver_errors=(None, OSError("busy"))) == []
    assert check(**one_refused) == []
    assert check(**quiet) == []  # a clean cycle in between: the count starts again
    assert check(**one_refused) == []
    assert check(bus_sent=np.array([4, 4, 4]), bus_errors=np.array([0, 0, 1]), driver_errors=()) == []  # can1 took frames
    assert check(**one_refused) == []
    (fault,) = check(**one_refused)  # the second consecutive refused cycle, no cause recorded
    assert fault.kind is FaultKind.BUS_OFF
    assert fault.message == "bus-off: the driver refused every frame for 2 cycles on can1"
    both = dict(bus_sent=np.array([4, 0, 0]), bus_errors=np.array([0, 3, 3]), driver_errors=(None, OSError("down")))
    check2 = Checker(g1, bus_names=("can0", "can1", "can2"))
    assert check2(**both) == []
    (fault,) = check2(**both)
    assert fault.message == "bus-off: the driver refused every frame for 2 cycles on can1 (OSError: down); can2"
    assert check2(**quiet) == [] and check2(**both) == []  # recovered: counting from one again


def test_driver_bugs_are_named_per_bus_at_once(g1) -> None:
    """A driver raising what no CAN driver should (not a CanError or an OSError) is a fault in
    the same cycle, naming each such bus; those buses are not reported bus-off as well."""
    check = Checker(g1, bus_names=("can0", "can1", "can2"))
    bugs = (RuntimeError("oops"), OSError("down"), KeyError("frame"))
    refused = dict(bus_sent=np.zeros(3, np.int64), bus_errors=np.ones(3, np.int64), driver_errors=bugs)
    (fault,) = check(**refused)
    assert fault.kind is FaultKind.DRIVER_ERROR
    assert fault.message == "bus driver raised: can0: RuntimeError: oops; can2: KeyError: 'frame'"
    kinds = [(f.kind, f.message) for f in check(**refused)]
    assert kinds[1] == (FaultKind.BUS_OFF, "bus-off: the driver refused every frame for 2 cycles on can1 (OSError: down)")


def test_motors_out_of_motor_mode_are_each_named(g1) -> None:
    status = np.ones(g1.dofs, np.int64)
    left, right = joint(g1, "left_knee_joint"), joint(g1, "right_knee_joint")
    status[[left, right]] = 0
    (fault,) = Checker(g1)(status=status)
    assert fault.kind is FaultKind.MOTOR_DISABLED and fault.joints == ("left_knee_joint", "right_knee_joint")
    assert fault.message == "motor(s) left motor mode (reply state 'disabled'): left_knee_joint, right_knee_joint"


def test_messages_list_every_offender(g1) -> None:
    names = g1.joint_names
    a, b = joint(g1, "left_knee_joint"), joint(g1, "right_knee_joint")
    dq = np.zeros(g1.dofs)
    dq[[a, b]] = 2 * g1.velocity_limits[[a, b]]
    (fault,) = Checker(g1)(dq=dq)
    assert fault.message == f"beyond velocity limits: {names[a]}={dq[a]:.1f} rad/s, {names[b]}={dq[b]:.1f} rad/s"
    tau = np.zeros(g1.dofs)
    tau[[a, b]] = 2 * g1.effort_limits[[a, b]]
    check = Checker(g1)
    check(tau=tau), check(tau=tau)
    (fault,) = check(tau=tau)
    assert fault.message == f"beyond torque limits for 3 cycles: {names[a]}={tau[a]:.1f} N m, {names[b]}={tau[b]:.1f} N m"
    stale = np.zeros(g1.dofs, np.int64)
    stale[[a, b]] = [3, 4]
    (fault,) = Checker(g1)(stale=stale)
    assert fault.message == f"no valid reply for >= 3 cycles: {names[a]} (3), {names[b]} (4)"
    (fault,) = Checker(g1, bus_names=("can0", "can1"))(corrupt=np.array([3, 4], np.int64))
    assert fault.message == "corrupt frames in the last 50 cycles on can0 (3), can1 (4)"
    check = Checker(g1)
    check()
    lower, upper = g1.position_limits
    q = check.q.copy()
    q[[a, b]] = upper[[a, b]]
    (fault,) = check(q=q)
    m = CONFIG.soft_limit_margin
    assert fault.message == ("beyond soft limits: " + ", ".join(
        f"{names[j]}={q[j]:.3f} not in [{lower[j] + m:.3f}, {upper[j] - m:.3f}]" for j in (a, b)))


# --- signals -----------------------------------------------------------------------------------
def test_installing_twice_still_restores_the_original_handler() -> None:
    original = signal.getsignal(signal.SIGINT)
    watch = SignalWatch()
    watch.install()
    watch.install()
    watch.restore()
    assert signal.getsignal(signal.SIGINT) is original and watch.installed is False
    watch.restore()  # a second restore changes nothing
    assert signal.getsignal(signal.SIGINT) is original


def _open_fds() -> set[str]:
    return set(os.listdir("/proc/self/fd"))


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs /proc to list open files")
def test_the_signal_watch_polls_without_blocking_and_restore_gives_everything_back() -> None:
    """``poll`` never waits (the control loop calls it every cycle); ``restore`` gives the
    interpreter its wake-up fd back and leaves no file open; a signal seen stays seen."""
    before_fd = signal.set_wakeup_fd(-1)
    signal.set_wakeup_fd(before_fd)
    files = _open_fds()
    watch = SignalWatch().install()
    try:
        assert watch.poll() is None and watch.poll() is None  # nothing delivered: returns at once
        os.kill(os.getpid(), signal.SIGHUP)
        assert watch.poll() == signal.SIGHUP
    finally:
        watch.restore()
    after_fd = signal.set_wakeup_fd(-1)
    signal.set_wakeup_fd(after_fd)
    assert after_fd == before_fd and _open_fds() == files
    assert watch.poll() == signal.SIGHUP and watch.name == "SIGHUP"

    fresh = SignalWatch()
    assert fresh.poll() is None  # never installed: nothing to read
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)
        fresh.install()
        fresh.restore()
        gc.collect()
    assert fresh.poll() is None and not [w for w in caught if issubclass(w.category, ResourceWarning)]


def test_poll_sees_a_signal_whose_python_handler_has_not_run() -> None:
    """The C-level handler writes the signal number to the wake-up fd at delivery; a control loop
    polling it sees the signal even if the main thread never ran the watch's Python handler (here
    replaced by one that does nothing)."""
    watch = SignalWatch().install()
    try:
        signal.signal(signal.SIGTERM, lambda signum, frame: None)
        os.kill(os.getpid(), signal.SIGTERM)
        assert watch.received is None
        assert watch.poll() == signal.SIGTERM and watch.name == "SIGTERM"
    finally:
        watch.restore()


def test_restoring_from_another_thread_leaves_the_watch_installed() -> None:
    """Handlers can only be changed from the main thread: a restore from the control loop's
    thread does nothing (no exception), and the main thread's restore still works."""
    original = signal.getsignal(signal.SIGTERM)
    watch = SignalWatch().install()
    errors = []

    def restore() -> None:
        try:
            watch.restore()
        except Exception as error:  # noqa: BLE001 - the test reports any
            errors.append(error)

    try:
        worker = threading.Thread(target=restore)
        worker.start()
        worker.join()
        assert errors == [] and watch.installed and signal.getsignal(signal.SIGTERM) is not original
    finally:
        watch.restore()
    assert not watch.installed and signal.getsignal(signal.SIGTERM) is original
