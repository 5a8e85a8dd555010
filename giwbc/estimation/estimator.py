"""The floating-base state estimator: what the CAN robot uses for the base state nothing measures.

Inputs are only what a real robot measures (the Robot interface's IMU, joints, efforts and time),
so the same code runs on MuJoCo sensor data and on CAN/IMU data:

0. calibration: the estimator is not ``ready`` until it has seen the robot stand still on both feet
   (:mod:`~giwbc.estimation.calibration`, detected from the samples, never assumed); from that
   window it takes the gyro bias, the base tilt (from flat feet, else gravity), the accelerometer
   bias and the offset of the IMU's orientation output, and restarts from them. Later standstill
   windows in double support re-estimate the gyro bias (zero-velocity updates);
1. orientation: a complementary filter on SO(3) (gyro propagation, gyro bias estimated) pulled
   toward, best first: the base orientation that flat stance feet imply (tilt from the joint
   encoders, heading held while the foot stays down and re-anchored only when it twists fast,
   :mod:`~giwbc.estimation.headings`, so the yaw gyro bias is learnt; a foot counts as flat while its centre of
   pressure, from the leg's efforts, is well inside the sole), the IMU's own orientation output
   (less its calibrated offset), or the accelerometer's gravity direction corrected by the base
   acceleration the stance legs measure;
2. contacts: normal force per foot from joint efforts (``J^T`` of each leg) or foot sensors,
   low-passed, through a hysteresis threshold, or the controller's contact plan passed to
   :meth:`StateEstimator.update`; a stance foot's load also sets how much it is trusted not to
   slip (a lightly loaded foot's velocity counts less);
3. position and velocity: a linear Kalman filter over IMU position/velocity and stance-foot
   positions, driven by the IMU acceleration and corrected by leg kinematics (Pinocchio); a foot
   whose velocity contradicts the IMU-propagated one (slip, impact) is down-weighted.

The IMU's own orientation output is assumed to share the world frame's yaw reference (true in
simulation and for an IMU whose yaw is zeroed at start); with ``use_imu_orientation=False`` only
roll and pitch are observed and yaw drifts with the gyro bias.

Output: an :class:`Estimate`: the base state, Pinocchio ``(q, v)`` for the whole-body controller,
contact flags and forces, covariance and fault diagnostics. Bad sensor data (NaN, saturated,
stale or backward timestamps) is flagged with a reason and counted, and never used: the update is
skipped (the last good estimate is held) or the bad channel is left out.

:class:`~giwbc.estimation.estimated_robot.EstimatedRobot` wraps a robot whose base is not measured (hardware, or a
:class:`~giwbc.robot.noise.NoisyRobot`) into a :class:`Robot` whose ``base_state()`` and
``generalized_state()`` come from the estimator, so a controller runs unchanged on it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pinocchio as pin

from giwbc.robot.description import RobotDescription
from giwbc.robot import so3
from giwbc.estimation.calibration import CalibrationReport, StandstillConfig, StandstillDetector, StandstillWindow
from giwbc.estimation.contacts import ContactDetector
from giwbc.estimation.faults import HOLDING_FAULTS, Fault, FaultMonitor, FaultReport
from giwbc.estimation.headings import FootHeadings
from giwbc.estimation import kernels

_HOLDING = int(HOLDING_FAULTS)
GRAVITY_NORM = 9.81
UNKNOWN_VARIANCE = 1e6  # covariance diagonal of an estimate not yet initialized (finite on purpose)
from giwbc.estimation.kalman import GRAVITY, LegKalmanFilter, LegKalmanNoise
from giwbc.estimation.kinematics import LegKinematics
from giwbc.estimation.orientation import OrientationFilter, gravity_error, quaternion_error, tilt_from_gravity
from giwbc.robot.interface import BaseState, ImuReading, Robot

__all__ = [
    "ANY_FEET",
    "CalibrationReport",
    "Estimate",
    "EstimatorConfig",
    "Fault",
    "FaultReport",
    "LegKalmanNoise",
    "Measurement",
    "StateEstimator",
]


@dataclass(frozen=True)
class EstimatorConfig:
    """Tuning of the estimator and the ranges of the sensors it checks.

    Contact thresholds are fractions of the robot's weight; the accelerometer and gyro ranges
    are the IMU's full scale (a reading within 0.1 % of it counts as saturated).
    """

    use_imu_orientation: bool = True  # pull toward the IMU's own orientation output (else gravity only)
    orientation_gain: float = 2.0  # 1/s
    gravity_gain: float = 0.5  # 1/s, accelerometer tilt correction when the orientation output is unusable
    gyro_bias_gain: float = 0.2  # 1/s^2
    noise: LegKalmanNoise = field(default_factory=LegKalmanNoise)
    ground_height: float | None = None  # flat ground at this height: stance feet measured on it
    ground_pull: float | None = None  # flat ground at this height: a still stance foot's height is pulled onto it ...
    ground_pull_time: float = 0.5  # s: ... with this time constant (the filter's own rows for ground_height cost a
    # second covariance for the z axis, ~13 us a tick; this costs a few float operations, and the foot's position rows
    # carry it to the base height)
    velocity_gate: float = 11.3  # normalized innovation (3 dof) above which a foot's velocity is down-weighted; 0: off
    velocity_gate_power: float = 1.0  # beyond the gate its noise variance grows as (innovation / gate)^power: 1 bounds a
    # foot's pull (Huber-like), 2 leaves a sliding foot out until the IMU's own velocity uncertainty has grown to it
    contact_on: float = 0.12  # x weight: a foot goes into contact above this normal force
    contact_off: float = 0.06  # x weight: ... and out of it below this one
    contact_filter_time: float = 0.01  # s, low-pass on contact forces before the thresholds
    contact_full: float = 0.25  # x weight: a stance foot with this load is fully trusted not to slip;
    # below it, its velocity counts less (down to contact_min_confidence at contact_off)
    contact_min_confidence: float = 0.1
    foot_roll_rate: float = 0.0  # rad/s: a stance foot turning this fast (rolling on an edge, rocking, slipping) counts
    # half (confidence / (1 + (rate / foot_roll_rate)^2)): not flat, its velocity trusted less; 0: off. 1.0 on feet that
    # rock (capsule / point soles): tilt error max 2-4 -> 0.5-0.8 deg walking; off by default as it drifts the nominal
    # plant's height more (0.8 -> 2 cm in 10 s) and changes the walking push scenarios the tests pin
    foot_roll_time: float = 0.02  # s: low-pass of the feet's squared angular rates before foot_roll_rate
    foot_roll_velocity: bool = True  # the turning foot's velocity and position trusted less too (else only not flat)
    pivot_velocity: bool = False  # a stance foot's velocity is its centre of pressure's (the point it rolls about), not
    # its sole centre's: v_cop = v_centre + w_foot x r_cop, the CoP from the leg's efforts clamped to the sole; a
    # turning foot's position (slip noise) is then trusted less, its pivot velocity not
    force_inertia: bool = False  # effort-based foot forces with the legs' inertial term: the joints' accelerations
    # (their velocities differentiated) and the base's (accelerometer, gyro differentiated), both low-passed by
    # force_inertia_time; without it a swinging leg's own dynamics read as ground force (G1: 60-200 N on a leg whose
    # foot is in the air, what a touch-down detector takes for a landing)
    force_inertia_time: float = 0.005  # s
    pulling_forces: bool = False  # keep an effort-based normal force below zero as estimated (a pull the ground cannot
    # exert: a leg's unmodelled dynamics); False: such a foot's force reads 0
    force_max_speed: float = 0.0  # m/s: a foot whose sole centre moves faster than this (estimated, world) carries no
    # force, one at half this speed or slower its full estimated force, linearly between: a loaded foot stands (G1
    # walking: 99 % of loaded ticks under 0.2-0.8 m/s on every plant variant), while the effort-based force of a swinging
    # leg is wrong most when it moves fast (false readings over 60 N at a median 1 m/s); 0: off
    roll_velocity_rate: float = 0.0  # rad/s: a stance foot turning faster than this has its confidence divided by
    # 1 + (rate / roll_velocity_rate)^2 (its instantaneous rate or its low-passed one, the larger) for its velocity row
    # and its slip noise (its position may follow it): a sole rolling on a rim, rocking or sinking into a soft floor
    # turns about a point that neither its centre nor its CoP from the efforts finds (0.1-0.4 m/s at 3-7 rad/s), and its
    # sole centre moves; the IMU carries the base velocity through the few tens of ms the roll lasts (0: off; it
    # overrides foot_roll_velocity)
    # s (0: off): the output base angular velocity is led by this much along its rate of change (the bias-corrected
    # gyro differentiated, low-passed over omega_lead_time): the gyro's sample is a tick or two old when the
    # controller acts on it, and on a stiff, lagged plant (all_at_once: point feet, a 0.01 s contact, 3-4 ms motor
    # lags) the WBC's damping on a base rate 4 ms late rocked the stance foot onto its ankle roll's soft limit (the
    # walker on the truth with only the base rate 2 ticks late: 16 of 16 walks ended; with noise of the same size:
    # 3 of 16). Only the estimate's output: the leg odometry keeps the measured rate.
    omega_lead: float = 0.0
    omega_lead_time: float = 0.005  # s
    gyro_range: float = math.radians(2000.0)  # rad/s
    accel_range: float = 16.0 * 9.80665  # m/s^2
    max_dt: float = 0.02  # s: a longer gap between IMU samples is flagged (TIME_GAP)
    initial_base_xy: tuple[float, float] = (0.0, 0.0)  # world x, y of the base at start (defines the frame)
    initial_ground_height: float = 0.0  # height of the ground the feet stand on at start
    initial_yaw: float = 0.0  # rad: base heading at start (defines the frame) when the IMU has no orientation output
    calibrate: bool = True  # not ready until a standstill calibration (False: ready at the first good sample)
    standstill: StandstillConfig = field(default_factory=StandstillConfig)
    zero_velocity_gain: float = 0.5  # share of a later standstill window's gyro mean taken into the bias
    use_flat_feet: bool = True  # orientation from flat stance feet (tilt, and heading held in stance)
    feet_gain: float = 2.0  # 1/s, pull toward the flat feet's base orientation (integral gain: feet_gain^2 / 4)
    flat_min_load: float = 0.5  # a foot counts as flat with at least this load confidence ...
    flat_cop_margin: float = 0.6  # ... and its centre of pressure within this fraction of the sole's half sizes
    flat_still_time: float = 0.03  # s: ... and turning slower than foot_roll_rate for this long (a rocking foot stops
    # for an instant at each end of its rock, tilted: no level reference)
    flat_max_tilt: float = math.pi  # rad: ... and its sole, at the estimated base orientation, within this of level (a
    # point or capsule foot resting on its toe-heel diagonal is still and its CoP central, but tilted: not a level
    # reference; the estimate's own tilt error is a few tenths of a degree, so a few degrees tell it apart)
    # rad (0: off): at the start-up calibration, feet that pass every flat test but flat_max_tilt (judged at the
    # estimate's pre-calibration orientation: the IMU's, mounting error included) still give the tilt when both
    # are loaded and their soles agree with each other within this (the ground the robot stands on is level)
    calibration_feet_agreement: float = 0.0
    accel_compensation_time: float = 0.1  # s: low-pass matching the accelerometer with the legs' velocity change
    foot_twist: float = math.radians(0.4)  # rad: a foot whose heading turned more than this ...
    foot_twist_time: float = 0.05  # s: ... within this time twisted on the ground (a slip; slower is gyro bias)
    max_gyro_bias: float = math.radians(20.0)  # rad/s per axis: the largest gyro bias the estimator believes
    orientation_offset_time: float = 5.0  # s: time constant of the orientation output's offset from the feet's

    @classmethod
    def for_sensors(cls, sensors: object, **overrides: object) -> "EstimatorConfig":
        """The configuration for an IMU described by ``sensors`` (a
        :class:`~giwbc.robot.noise.SensorNoiseConfig` or anything with an ``orientation_output``
        flag): its orientation output is used when it has one."""
        use = bool(getattr(sensors, "orientation_output", True))
        return cls(**{"use_imu_orientation": use, **overrides})  # type: ignore[arg-type]

    def __post_init__(self) -> None:
        if not (0.0 <= self.calibration_feet_agreement < math.pi / 2):
            raise ValueError(f"calibration_feet_agreement must be in [0, pi/2) rad, got {self.calibration_feet_agreement!r}")
        if not 0 <= self.contact_off < self.contact_on:
            raise ValueError("contact thresholds need 0 <= contact_off < contact_on")
        if min(self.orientation_gain, self.gravity_gain, self.gyro_bias_gain, self.feet_gain) < 0 or self.max_dt <= 0:
            raise ValueError("gains must be >= 0 and max_dt > 0")
        if not 0 <= self.zero_velocity_gain <= 1 or not 0 < self.flat_cop_margin <= 1:
            raise ValueError("zero_velocity_gain must be in [0, 1] and flat_cop_margin in (0, 1]")
        if self.accel_compensation_time <= 0 or self.orientation_offset_time <= 0:
            raise ValueError("accel_compensation_time and orientation_offset_time must be > 0")
        if self.foot_twist <= 0 or self.foot_twist_time <= 0:
            raise ValueError("foot_twist and foot_twist_time must be > 0")
        if not self.ground_pull_time > 0:
            raise ValueError("ground_pull_time must be > 0")
        if not self.force_inertia_time > 0 or not self.force_max_speed >= 0:
            raise ValueError("force_inertia_time must be > 0 and force_max_speed >= 0")
        if not (self.omega_lead >= 0 and self.omega_lead_time > 0):
            raise ValueError("omega_lead must be >= 0 and omega_lead_time > 0")
        if not self.roll_velocity_rate >= 0:
            raise ValueError("roll_velocity_rate must be >= 0")
        if not (self.foot_roll_rate >= 0 and self.flat_still_time >= 0 and self.foot_roll_time >= 0):
            raise ValueError("foot_roll_rate, foot_roll_time and flat_still_time must be >= 0")


# EstimatorConfig fields for feet that are not the flat box of the description (issue 41: points,
# capsules, rounded soles, a soft floor) on flat ground. Walker on the truth, estimator alongside
# (AHRS profile), 0.3 m/s for 10 s, tuning seeds 20000-20002; without -> with, worst variant:
# tilt error max 3.5-7 -> 0.4-1.5 deg, height drift 2-6 -> 0.4-0.6 cm, velocity RMS about 20 % less.
# - foot_roll_rate 1 rad/s without foot_roll_velocity: a turning foot is no level reference (tilt
#   error: point feet 3.5 -> 0.7 deg), but its velocity is still used (taking it less made the
#   velocity error 0.03-0.06 -> 0.23-0.39 m/s: the feet that rock are the ones the base stands on);
# - pivot_velocity: the velocity of the CoP, the point a rolling foot turns about, not of the sole
#   centre (capsule 0.071 -> 0.052 m/s, point 0.044 -> 0.034);
# - ground_pull 0 (the ground the robot started on, flat): a still stance foot's height pulled onto it
#   (height drift walking forward comes from a pitch error times the distance: 0.17 deg gives 7 mm in 3 m);
# - flat_max_tilt 1.5 deg: a foot resting tilted (point feet on their toe-heel diagonal: "flat"
#   feet were up to 5.6 deg off level, p99) is no level reference (point feet, seed 20003:
#   tilt error max 1.22 -> 0.41 deg);
# - velocity_gate_power 2: a foot whose velocity contradicts the IMU's beyond the gate is left out
#   rather than pulling with a bounded force (nominal 0.027 -> 0.019 m/s, point feet 0.034 -> 0.028).
# - force_inertia: the legs' inertial term in the effort-based foot forces; force_max_speed 1 m/s: a
#   foot moving faster carries no force (a swinging leg read 100-215 N on capsule feet while in the
#   air, a false touch-down; replayed walks, seeds 20000-20001, swing-foot force p99 nominal 81 -> 11 N,
#   capsule 230 -> 16 N, frictional joints 362 -> 36 N);
# - calibration_feet_agreement 1.5 deg: at the start-up calibration, two resting feet whose soles
#   agree with each other give the tilt even when the IMU's (mis-mounted) gravity puts them past
#   flat_max_tilt (all_at_once, tuning seed 20000: both feet judged tilted, the tilt taken from the
#   accelerometer, 1.6 deg off from the first tick; with it 0.09 deg as at seeds 20001-20003);
# - roll_velocity_rate 0.5 rad/s: a turning stance foot's velocity and standing still trusted less,
#   the IMU carrying the base through the roll (a foot rocking on its rim or into a soft floor moved
#   the estimate by 0.2-0.4 m/s: velocity RMS soft floor 0.108 -> 0.040, capsule 0.131 -> 0.027,
#   nominal 0.017 -> 0.015 m/s; in the closed loop soft_floor walks 4/4 where it ended 4/4).
# - omega_lead 10 ms: the output base rate led along its derivative (the walker on the estimate, all_at_once,
#   0.3 m/s 20 s, seeds 20000-20003 and 30008-30019: ends 14 -> 5 of 16, what the true base twist gives; lead
#   4 ms, the sensor's own lag: 11; 15 ms: 2); nominal and point feet, seeds 20000-20003: ends 0 -> 0, 1 -> 0.
# Opt-in (giwbc.runtimes.estimated.EstimatorInLoop uses it): it changes the estimate on the nominal
# plant too (better: velocity 0.029 -> 0.027 m/s, height drift 7 -> 4 mm) and so the seed-pinned
# deployment walks; the ground prior is wrong off flat ground.
ANY_FEET: dict[str, object] = {
    "foot_roll_rate": 1.0, "foot_roll_velocity": False, "pivot_velocity": True, "ground_pull": 0.0,
    "velocity_gate_power": 2.0, "flat_max_tilt": math.radians(1.5),
    "force_inertia": True, "force_max_speed": 1.0, "roll_velocity_rate": 0.5,
    "calibration_feet_agreement": math.radians(1.5), "omega_lead": 0.01,
}


@dataclass(frozen=True)
class Measurement:
    """What one read of a robot's sensors returns; ``time`` is the IMU sample's timestamp.

    ``contact_forces``: optional measured normal force per contact (N, description order), from
    foot force sensors; without it, contact forces are estimated from joint efforts.
    """

    imu: ImuReading
    joint_positions: np.ndarray
    joint_velocities: np.ndarray
    joint_efforts: np.ndarray
    contact_forces: np.ndarray | None = None

    @property
    def time(self) -> float:
        return float(self.imu.time)

    @classmethod
    def from_robot(cls, robot: Robot) -> "Measurement":
        """The measured quantities of ``robot`` (never its base state)."""
        return cls(robot.imu(), robot.joint_positions(), robot.joint_velocities(), robot.joint_efforts())


@dataclass(frozen=True)
class Estimate:
    """The estimator's output after one update.

    ``q``/``v`` are Pinocchio's free-flyer convention (``[p, quat_xyzw, joints]`` /
    ``[v_local, w_local, joints]``), ready for the whole-body controller; the joints are the
    encoder readings (last good value for a bad one). Per contact (description order):
    ``contacts`` (flags used), ``contact_confidence`` (0 swing, up to 1 for a fully loaded
    stance foot), ``contact_forces`` (world-frame ground force at the sole centre, estimated or
    measured). ``covariance``: base position/velocity covariance (6, 6, world); ``gyro_bias``:
    estimated gyro bias (IMU frame); ``time``: timestamp of the last accepted measurement;
    ``faults``: what was wrong with this update; ``initialized``: False until the first good
    measurement (until then the description's default pose); ``ready``: the start-up calibration
    is done (never before the robot stood still): hand the estimate to a controller only then.
    """

    time: float
    base: BaseState
    q: np.ndarray
    v: np.ndarray
    contacts: np.ndarray
    contact_confidence: np.ndarray
    contact_forces: np.ndarray
    covariance: np.ndarray
    gyro_bias: np.ndarray
    faults: FaultReport
    initialized: bool = True
    ready: bool = True

    @property
    def covariance_trace(self) -> float:
        return float(np.trace(self.covariance))


class StateEstimator:
    """Estimates the floating base of ``description`` from IMU, encoders, efforts and contacts.

    Call :meth:`update` once per new sample (typically each control tick, e.g. 500 Hz) with a
    :class:`Measurement` and, optionally, the controller's contact plan; it returns an
    :class:`Estimate`. :attr:`fault_counts` counts every fault since construction or :meth:`reset`.
    """

    def __init__(
        self, description: RobotDescription, config: EstimatorConfig | None = None, model: pin.Model | None = None
    ) -> None:
        self.description = description
        self.config = config if config is not None else EstimatorConfig()
        c = self.config
        self.kinematics = LegKinematics(description, model)
        n_feet, dofs = self.kinematics.n_feet, description.dofs
        weight = description.total_mass * -GRAVITY[2]
        self.orientation = OrientationFilter(c.orientation_gain, c.gravity_gain, c.gyro_bias_gain, c.max_gyro_bias)
        self.filter = LegKalmanFilter(n_feet, c.noise, use_ground_height=c.ground_height is not None, velocity_gate=c.velocity_gate,
                                     gate_power=c.velocity_gate_power)
        self.detector = ContactDetector(
            n_feet, c.contact_on * weight, c.contact_off * weight, c.contact_filter_time, c.contact_full * weight
        )
        self._imu_rotation = tuple(self.kinematics.imu_rotation.ravel().tolist())  # IMU frame in base frame, row by row
        self._imu_offset_base = tuple(self.kinematics.imu_position.tolist())  # IMU position in the base frame
        self._imu_to_base = tuple(so3.quat_conjugate(so3.matrix_to_quat(self.kinematics.imu_rotation)).tolist())
        self._gravity = tuple(GRAVITY.tolist())
        leg_joints = [self.kinematics.leg_joints(i) for i in range(n_feet)]
        self._leg_mask = np.zeros((n_feet, dofs), dtype=bool)  # which joints each foot's kinematics uses
        for i, joints in enumerate(leg_joints):
            self._leg_mask[i, joints] = True
        self._dofs = dofs
        self._nq, self._nv = self.kinematics.model.nq, self.kinematics.model.nv
        self._all_feet = np.ones(n_feet, dtype=bool)
        self._all_feet.flags.writeable = False
        self._leg_joint_index = np.flatnonzero(self._leg_mask.any(axis=0))
        self._sole_half = [(c.half_length, c.half_width) for c in description.contacts]
        self._sole_half_array = np.array(self._sole_half, dtype=float)
        self._flat_cos = math.cos(min(self.config.flat_max_tilt, math.pi))  # a sole's world z-z component at least this
        self.standstill = StandstillDetector(c.standstill, self._leg_joint_index)
        self.headings = FootHeadings(n_feet, c.foot_twist, c.foot_twist_time)
        self._warm_up()
        self.reset()

    def _warm_up(self) -> None:
        """Run this configuration's compiled kernels once now (:mod:`~giwbc.estimation.kernels`): the
        first call in a process compiles a kernel (~13 s for all on a fresh machine) or loads it from
        numba's disk cache (~0.3 s), which must not happen in a real-time loop's first cycles.
        Three synthetic updates at the default pose, standing: a start, a normal one, one with a bad
        encoder (the fault path's argument types); :meth:`reset` forgets them."""
        self.reset()
        positions = self.description.default_positions.astype(float)
        zeros = np.zeros(self._dofs)
        imu = self.kinematics.imu_rotation.T @ np.array([0.0, 0.0, -GRAVITY[2]])
        for k in range(3):
            bad = positions.copy()
            if k == 2:
                bad[self._leg_joint_index[0]] = np.nan
            reading = ImuReading(so3.matrix_to_quat(self.kinematics.imu_rotation), np.zeros(3), imu, 0.002 * k)
            self.update(Measurement(reading, bad, zeros, zeros))

    # --- public ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget everything: the next good measurement initializes the estimate, and it is not
        :attr:`ready` until a new standstill calibration (a simulated reset, a restart)."""
        self.monitor = FaultMonitor()
        self.orientation.initialized = False
        self.detector.reset()
        self.standstill.reset()
        startup = self.config.standstill.startup_blocks
        self.standstill.blocks = startup if startup is not None and self.config.calibrate else self.config.standstill.blocks
        self.calibration: CalibrationReport | None = None
        self.zero_velocity_updates = 0
        self._ready = not self.config.calibrate
        self._restart_filter = False
        self._restart_pending = False
        self._accel_bias = (0.0, 0.0, 0.0)
        self._output_offset = (0.0, 0.0, 0.0)  # rotation vector (IMU frame) from the orientation output to the estimate
        self.headings.reset()
        self._flat = [False] * self.kinematics.n_feet
        self._resting = [False] * self.kinematics.n_feet  # flat but for flat_max_tilt (the calibration's agreement test)
        self._still_since = np.full(self.kinematics.n_feet, -math.inf)  # s: when each foot last turned faster than foot_roll_rate
        self._rate2 = np.zeros(self.kinematics.n_feet)  # (rad/s)^2: each foot's squared angular rate, low-passed
        self._velocity_rate2 = np.zeros(self.kinematics.n_feet)  # the same for roll_velocity_rate
        self._trust = np.zeros(self.kinematics.n_feet)  # the foot-trust kernels' output
        self._up_lp = np.zeros(6)  # low-passed, world: the specific force, then the IMU velocity from the stance legs
        self._up_started = False  # whether _up_lp holds a first sample
        self.reference = "none"  # the orientation reference of the last update: feet, orientation_output, gravity
        self._output_heading: list[float] | None = None  # low-passed (cos, sin) of the base heading the orientation output gives
        self._time: float | None = None
        self._positions = self.description.default_positions.copy()
        self._velocities = np.zeros(self._dofs)
        self._efforts = np.zeros(self._dofs)
        self._forces = np.zeros((self.kinematics.n_feet, 3))
        self._joint_velocity_lp = np.zeros(self._dofs)  # force_inertia: low-passed joint velocities ...
        self._joint_acceleration = np.zeros(self._dofs)  # ... and their derivative
        self._base_motion_lp = np.zeros(6)  # low-passed base angular velocity (base frame), IMU acceleration (world)
        self._inertia_started = False  # whether the two low-passes above hold a first sample
        self._base_acceleration = np.zeros(6)  # the base's acceleration (base frame: linear, angular) they give
        self._pivot_velocities = np.zeros((self.kinematics.n_feet, 3))
        self._omega_last: so3.Vector3 | None = None  # omega_lead: the last base rate (base frame) ...
        self._omega_rate = (0.0, 0.0, 0.0)  # ... and its low-passed derivative
        self._foot_lists: tuple[list, list] | None = None
        self._estimate = self._initial_estimate()

    @property
    def ready(self) -> bool:
        """Whether the start-up calibration is done (see :meth:`update`)."""
        return self._ready

    @property
    def waiting_for(self) -> str:
        """Why the estimator is not :attr:`ready` yet, for a person ("" once ready)."""
        if self._ready:
            return ""
        if not self.orientation.initialized:
            return "no usable IMU sample yet"
        if self.calibration is not None:
            return "calibrated: restarting from it at the next sample"
        return f"a standstill on both feet ({self.standstill.rejection})"

    @property
    def foot_twists(self) -> int:
        """Stance feet that twisted on the ground (slipped) and were re-anchored since the last reset."""
        return self.headings.twists

    @property
    def pivot_velocities(self) -> np.ndarray:
        """Per contact (world axes, relative to a non-translating IMU): the velocity of its centre of
        pressure in the last update with ``pivot_velocity`` (zeros without)."""
        return self._pivot_velocities.copy()

    @property
    def flat_feet(self) -> np.ndarray:
        """Per contact: counted as a flat stance foot in the last update."""
        return np.array(self._flat)

    @property
    def estimate(self) -> Estimate:
        """The latest estimate (``initialized`` is False until a good measurement arrived)."""
        return self._estimate

    @property
    def fault_counts(self) -> dict[str, int]:
        """Faults counted per kind since construction or the last reset."""
        return dict(self.monitor.counts)

    def update_from_robot(self, robot: Robot, contacts: np.ndarray | None = None) -> Estimate:
        """:meth:`update` with ``robot``'s measured quantities."""
        return self.update(Measurement.from_robot(robot), contacts)

    def update(self, measurement: Measurement, contacts: np.ndarray | None = None) -> Estimate:
        """Fuse one measurement. ``contacts``: the controller's contact plan (one bool per
        contact, description order); it overrides force-based detection for this update.

        3-vectors, quaternions and per-foot values are handled as Python floats (``so3.*_floats``):
        at one sample per control tick, numpy's per-call overhead would cost more than their
        arithmetic; numpy and Pinocchio take the joint-sized and matrix work."""
        monitor, c = self.monitor, self.config
        imu = measurement.imu
        now = float(imu.time)
        self._check_time(now)
        gyro = self._read_vector(imu.angular_velocity, c.gyro_range, Fault.GYRO_INVALID, Fault.GYRO_SATURATED, "gyro")
        accel = self._read_vector(
            imu.linear_acceleration, c.accel_range, Fault.ACCEL_INVALID, Fault.ACCEL_SATURATED, "accelerometer"
        )
        orientation = self._imu_orientation(imu.quaternion)  # validated quaternion or None
        plan = self._contact_plan(contacts)
        if monitor.has(_HOLDING):
            return self._hold()
        position_ok, velocity_ok, effort_ok = self._read_joints(measurement)
        starting = not self.orientation.initialized
        if starting:
            if not self._start_orientation(orientation, accel):
                monitor.flag(Fault.ORIENTATION_INVALID, "no usable IMU orientation or gravity to start from: not initialized")
                return self._hold()
            dt = 0.0
        else:
            dt = now - self._time
            self.orientation.propagate(gyro, dt)
        self._time = now

        base_quaternion, base_rotation, base_omega = self._base_attitude(gyro)
        use_efforts = measurement.contact_forces is None
        try:
            efforts = self._efforts if use_efforts else None
            base_acceleration = None
            if c.force_inertia and use_efforts:
                base_acceleration = self._leg_accelerations(base_rotation, base_omega, accel, dt)
            self.kinematics.compute(base_quaternion, base_omega, self._positions, self._velocities, efforts,
                                    base_acceleration, self._joint_acceleration)
        except np.linalg.LinAlgError:  # a leg at a singularity: no effort-based forces this update
            use_efforts, effort_ok = False, np.zeros_like(effort_ok)
        self._foot_lists = None  # this update's kinematics as Python floats, made on first use
        stance = self._detect_contacts(measurement, effort_ok, use_efforts, plan, dt)
        flags = stance.tolist()
        loads = self._stance_confidence(flags)
        still = self._still_feet(loads, dt) if c.foot_roll_rate > 0.0 else loads
        velocities = self.kinematics.foot_velocities
        if c.pivot_velocity and use_efforts:
            velocities = self._pivot_velocity()
            positions_trust = still if c.foot_roll_velocity else loads  # a rolling foot's sole centre moves: its position may follow
        elif c.foot_roll_velocity:
            loads = positions_trust = still
        else:
            positions_trust = loads
        velocity_trust = loads
        if c.roll_velocity_rate > 0.0:  # a turning foot's velocity and its standing still both trusted less
            velocity_trust = positions_trust = self._rolling_velocity_trust(loads, dt)
        self._correct_orientation(orientation, accel, base_rotation, flags, still, use_efforts, position_ok, dt)
        if accel is not None:
            window = self.standstill.add(now, gyro, accel, self._positions, min(loads))
            if window is not None:
                self._standstill_window(window, orientation, base_rotation, flags)
            ax, ay, az = accel
            bx, by, bz = self._accel_bias
            accel = [ax - bx, ay - by, az - bz]
        if starting or self._restart_filter:
            self._initialize_filter(stance)
            if self._restart_filter and self.calibration is not None:
                self._ready = True  # calibrated, and the filter restarted from it
            self._restart_filter = False
        elif self._restart_pending:  # calibrated in this update: restart the filter on the next one's kinematics
            self._restart_filter, self._restart_pending = True, False
            self.filter.predict(None if accel is None else self._world_acceleration(base_rotation, accel), dt, positions_trust)
            self.filter.correct(
                self.kinematics.foot_positions, velocities, velocity_trust, position_ok, velocity_ok,
                0.0 if c.ground_height is None else c.ground_height,
            )
        else:
            self.filter.predict(None if accel is None else self._world_acceleration(base_rotation, accel), dt, positions_trust)
            if not any(flags):
                monitor.flag(Fault.NO_STANCE_FOOT, "no foot in contact: base velocity from the IMU alone")
            self.filter.correct(
                self.kinematics.foot_positions, velocities, velocity_trust, position_ok, velocity_ok,
                0.0 if c.ground_height is None else c.ground_height,
            )
            if c.ground_pull is not None:
                self._pull_to_ground(flags, loads, dt)
        if c.omega_lead > 0.0:
            base_omega = self._led_omega(base_omega, dt)
        self._estimate = self._make_estimate(
            base_rotation, base_quaternion, base_omega, stance, np.array(loads), monitor.finish()
        )
        return self._estimate

    # --- orientation references and calibration -------------------------------------------------
    def _start_orientation(self, output: list[float] | None, accel: list[float] | None) -> bool:
        """Start from the IMU's orientation output, else from gravity with the configured base heading."""
        if output is not None or accel is None:
            return self.orientation.initialize(output, None)
        if math.sqrt(sum(a * a for a in accel)) < 0.5 * GRAVITY_NORM:
            return False
        imu_in_base = self.kinematics.imu_rotation
        base = tilt_from_gravity(imu_in_base @ np.asarray(accel, float), self.config.initial_yaw)
        self.orientation.reset_to(so3.matrix_to_quat(base @ imu_in_base), (0.0, 0.0, 0.0))
        return True

    def _correct_orientation(
        self, output: list[float] | None, accel: list[float] | None, base_rotation: so3.Matrix3, flags: list[bool],
        loads: list[float], use_efforts: bool, position_ok: np.ndarray, dt: float,
    ) -> None:
        """Pick this update's orientation reference (flat feet, the IMU's orientation output, or
        compensated gravity) and hand its error to the orientation filter."""
        c, filt = self.config, self.orientation
        if output is not None and not self._ready:  # average the output's heading for the calibration
            self._average_output_heading(output)
        up = self._compensated_up(accel, base_rotation, flags, loads, dt) if accel is not None else None
        feet = self._flat_feet_error(flags, loads, use_efforts, position_ok) if c.use_flat_feet else None
        if feet is not None:
            error = so3.rotate_back(self._imu_rotation, so3.rotate_back(base_rotation, feet))
            filt.correct(error, c.feet_gain, 0.25 * c.feet_gain * c.feet_gain, dt)
            self.reference = "feet"
            if output is not None:  # learn the orientation output's offset from the feet's orientation
                ox, oy, oz = self._output_offset
                ex, ey, ez = quaternion_error(_rotated(output, self._output_offset), filt.quaternion_floats)
                k = dt / c.orientation_offset_time
                self._output_offset = (ox + k * ex, oy + k * ey, oz + k * ez)
        elif output is not None:
            reference = _rotated(output, self._output_offset)
            filt.correct(quaternion_error(filt.quaternion_floats, reference), c.orientation_gain, c.gyro_bias_gain, dt)
            self.reference = "orientation_output"
        elif up is not None:
            filt.correct(gravity_error(filt.quaternion_floats, up), c.gravity_gain, 0.25 * c.gravity_gain * c.gravity_gain, dt)
            self.reference = "gravity"
        else:
            filt.correct(None, 0.0, 0.0, dt)
            self.reference = "none"

    def _average_output_heading(self, output: list[float]) -> None:
        """Low-pass (0.25 s at 500 Hz) the base heading of the orientation output: its per-sample
        noise would otherwise set the heading the feet then hold."""
        r = so3.quat_to_matrix_floats(so3.quat_multiply_floats(output, self._imu_to_base))
        cos, sin = r[0], r[3]
        norm = math.hypot(cos, sin)
        if norm < 1e-6:
            return
        heading = self._output_heading
        if heading is None:
            self._output_heading = [cos / norm, sin / norm]
        else:
            heading[0] += 0.008 * (cos / norm - heading[0])
            heading[1] += 0.008 * (sin / norm - heading[1])

    def _flat_feet_error(
        self, flags: list[bool], loads: list[float], use_efforts: bool, position_ok: np.ndarray
    ) -> so3.Vector3 | None:
        """World-frame rotation vector from the estimated base orientation to the one the flat
        stance feet imply (each sole level, its heading held since it came down), averaged over
        the flat feet; None without one. A foot is flat while loaded and with its centre of
        pressure (from the leg's efforts) well inside the sole."""
        c, kin = self.config, self.kinematics
        margin, min_load, headings, now = c.flat_cop_margin, c.flat_min_load, self.headings, self._time
        still_time = c.flat_still_time
        lists = self._kinematics_lists()
        wrenches = lists[0] if use_efforts else None
        rotations = lists[1]
        valid = [True] * len(flags) if position_ok is self._all_feet else position_ok.tolist()
        still_since = self._still_since.tolist()
        ex = ey = ez = 0.0
        count = 0
        yaw_error, yaw_count = 0.0, 0
        for i, (standing, load) in enumerate(zip(flags, loads)):
            loaded = standing and load >= min_load and valid[i]
            (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = rotations[i]
            flat = loaded and now - still_since[i] >= still_time
            if loaded:  # a loaded foot keeps its heading, even rolling on an edge, unless it twists (a slip)
                yaw_error += headings.update(i, now, math.atan2(m10, m00))
                yaw_count += 1
            elif not standing:
                headings.lift(i)
            if flat and wrenches is not None:
                _, _, fz, tx, ty, _ = wrenches[i]
                if fz <= 0.0:
                    flat = False
                else:
                    px, py = -ty / fz, tx / fz  # centre of pressure from the sole centre, world axes
                    half_length, half_width = self._sole_half[i]
                    flat = abs(m00 * px + m10 * py) <= margin * half_length and abs(m01 * px + m11 * py) <= margin * half_width
            self._resting[i] = flat
            if flat and m22 < self._flat_cos:
                flat = False
            self._flat[i] = flat
            if not flat:
                continue
            yaw = headings.held[i]  # set: a flat foot is loaded
            cy, sy = math.cos(yaw), math.sin(yaw)
            # vee of (E - E^T) / 2 with E = Rz(yaw) R_foot^T: the world rotation that levels the sole at its heading
            ex += 0.5 * (m12 - sy * m20 - cy * m21)
            ey += 0.5 * (cy * m20 - sy * m21 - m02)
            ez += 0.5 * (sy * m00 + cy * m01 - cy * m10 + sy * m11)
            count += 1
        if not count:
            return None if not yaw_count else (0.0, 0.0, yaw_error / yaw_count)
        return (ex / count, ey / count, ez / count)

    def _compensated_up(self, accel: list[float], base_rotation: so3.Matrix3, flags: list[bool], loads: list[float], dt: float) -> so3.Vector3:
        """The accelerometer's gravity (IMU frame): its specific force less its calibrated bias,
        less the IMU acceleration the stance legs measure. Both are low-passed alike in the world
        frame (the acceleration as the derivative of the low-passed leg velocity), so the legs'
        velocity noise is not differentiated (:func:`giwbc.estimation.kernels.compensated_up`)."""
        tau = self.config.accel_compensation_time
        alpha, rate = (dt / (tau + dt), 1.0 / (tau + dt)) if self._up_started else (1.0, 0.0)
        up = kernels.compensated_up(tuple(accel), self._accel_bias, base_rotation, self._imu_rotation, tuple(loads),
                                    self.kinematics.foot_velocities, self.filter.x, self._up_lp, not self._up_started, alpha, rate)
        self._up_started = True
        return up

    def _standstill_window(self, window: StandstillWindow, output: list[float] | None, base_rotation: so3.Matrix3, flags: list[bool]) -> None:
        """A standstill window ended: the start-up calibration, or a zero-velocity update of the
        gyro bias (and, with flat feet holding the tilt, of the accelerometer bias)."""
        c = self.config
        if not all(flags):
            self.standstill.rejection = "still, but not on both feet (contact flags)"
            return
        if self.calibration is None and c.calibrate:
            self._calibrate(window, output, base_rotation)
            return
        k = c.zero_velocity_gain
        bias = np.asarray(self.orientation.gyro_bias_floats)
        self.orientation.set_gyro_bias(bias + k * (window.gyro - self._window_rotation(window) - bias))
        if self.reference == "feet" and all(self._flat):
            rotation = np.asarray(base_rotation).reshape(3, 3) @ self.kinematics.imu_rotation
            accel_bias = np.asarray(self._accel_bias)
            self._accel_bias = tuple((accel_bias + k * (window.accel - GRAVITY_NORM * rotation[2] - accel_bias)).tolist())
        self.zero_velocity_updates += 1

    def _window_rotation(self, window: StandstillWindow) -> np.ndarray:
        """The base's mean angular velocity over a standstill window (IMU frame), what the gyro
        read besides its bias: with both feet flat on the ground, from the leg encoders (the soles
        stay put, so the base turned by R_bf(q_first) R_bf(q_last)^T: exact, and blind to the IMU's
        own acceleration in a slow sway, which the gravity direction is not); otherwise the turn
        of the gravity direction (tilt only)."""
        if not (self.config.use_flat_feet and all(self._flat)) or window.span <= 0.0:
            return window.tilt_rate
        first, last = self._positions.copy(), self._positions.copy()
        first[self._leg_joint_index], last[self._leg_joint_index] = window.first_joints, window.last_joints
        turns = [so3.log(r0 @ r1.T) for r0, r1 in zip(self.kinematics.sole_rotations(first), self.kinematics.sole_rotations(last))]
        return self.kinematics.imu_rotation.T @ (np.mean(turns, axis=0) / window.span)

    def _calibrate(self, window: StandstillWindow, output: list[float] | None, base_rotation: so3.Matrix3) -> None:
        """Start-up calibration from a standstill window in double support (module doc)."""
        c, kin = self.config, self.kinematics
        imu_in_base = kin.imu_rotation
        accel = window.accel
        accel_up = imu_in_base @ (accel / np.linalg.norm(accel))  # gravity's direction, base frame
        rotation = np.asarray(base_rotation).reshape(3, 3)
        ups = rotation.T @ kin.foot_rotations[:, :, 2].T  # each sole's normal (world z if flat), base frame
        agree = c.calibration_feet_agreement > 0.0 and all(self._resting) and len(self._resting) > 1 and bool(
            (ups.T @ ups).min() >= math.cos(c.calibration_feet_agreement))
        if c.use_flat_feet and (all(self._flat) or agree):
            up = ups.mean(axis=1)
            up /= np.linalg.norm(up)
            source = "feet"
        else:
            up, source = accel_up, "gravity"
        yaw = c.initial_yaw
        if output is not None and self._output_heading is not None:
            yaw = math.atan2(self._output_heading[1], self._output_heading[0])
        base = tilt_from_gravity(up, yaw)
        imu = so3.matrix_to_quat(base @ imu_in_base)
        gyro_bias = window.gyro - self._window_rotation(window)
        self.orientation.reset_to(imu, gyro_bias)
        if source == "feet":
            accel_bias = accel - GRAVITY_NORM * (imu_in_base.T @ up)
        else:  # tilt and a horizontal bias are one unknown: only the magnitude is calibrated
            accel_bias = accel - GRAVITY_NORM * accel / np.linalg.norm(accel)
        self._accel_bias = tuple(accel_bias.tolist())
        offset = None
        if output is not None:
            self._output_offset = quaternion_error(output, imu.tolist())
            offset = math.sqrt(sum(e * e for e in self._output_offset))
        self.headings.reset()
        self._up_started = False
        self._restart_pending = True
        self.standstill.blocks = c.standstill.blocks  # later windows: zero-velocity updates
        self.calibration = CalibrationReport(
            time=window.end_time, gyro_bias=gyro_bias, accel_bias=accel_bias, roll=math.atan2(base[2, 1], base[2, 2]),
            pitch=-math.asin(max(-1.0, min(1.0, base[2, 0]))), tilt_source=source,
            accel_tilt_disagreement=math.acos(max(-1.0, min(1.0, float(accel_up @ up)))),
            orientation_output_offset=offset, window_duration=window.duration, window_samples=window.samples,
            gyro_std=window.gyro_std, accel_std=window.accel_std,
        )  # fmt: skip

    # --- checks ---------------------------------------------------------------------------
    def _check_time(self, now: float) -> None:
        last, monitor = self._time, self.monitor
        if last is not None and 0.0 < now - last <= self.config.max_dt:  # fast path; False for NaN
            return
        if not math.isfinite(now):
            monitor.flag(Fault.TIME_INVALID, f"IMU timestamp is {now}: update skipped")
        elif last is not None and now == last:
            monitor.flag(Fault.STALE_TIMESTAMP, f"IMU timestamp {now} repeats the last accepted one: update skipped")
        elif last is not None and now < last:
            monitor.flag(Fault.TIME_BACKWARDS, f"IMU timestamp {now} is before the last accepted {last}: update skipped")
        elif last is not None and now - last > self.config.max_dt:
            monitor.flag(Fault.TIME_GAP, f"{now - last:.4f} s since the last IMU sample (> {self.config.max_dt} s)")

    def _read_vector(self, value: np.ndarray, limit: float, invalid: Fault, saturated: Fault, name: str) -> list[float] | None:
        """A 3-vector reading as Python floats, or None (flagged) when not 3 finite numbers or
        saturated (within 0.1 % of the sensor's range ``limit``)."""
        value = np.asarray(value, float)
        if value.shape == (3,):
            x, y, z = floats = value.tolist()
            bound = 0.999 * limit
            if abs(x) < bound and abs(y) < bound and abs(z) < bound:  # fast path; False for NaN
                return floats
        if value.shape != (3,) or not np.isfinite(value).all():
            self.monitor.flag(invalid, f"{name} reading {value} is not 3 finite numbers")
        else:
            self.monitor.flag(saturated, f"{name} reading {value} is at its range +-{limit:g}")
        return None

    def _imu_orientation(self, quaternion: np.ndarray | None) -> list[float] | None:
        """The IMU's orientation output (a unit quaternion, as Python floats), or None when
        unusable or unused."""
        if not self.config.use_imu_orientation or quaternion is None:
            return None
        quaternion = np.asarray(quaternion, float)
        if quaternion.shape == (4,):
            x, y, z, w = floats = quaternion.tolist()
            if abs(x * x + y * y + z * z + w * w - 1.0) <= 0.02:  # False for NaN (and inf gives inf)
                return floats
        reason = f"IMU orientation {quaternion} is not a unit quaternion: gravity used instead"
        self.monitor.flag(Fault.ORIENTATION_INVALID, reason)
        return None

    def _contact_plan(self, contacts: np.ndarray | None) -> np.ndarray | None:
        if contacts is None:
            return None
        plan = np.array(contacts, dtype=bool)  # a copy: estimates must not change with the caller's array
        if plan.shape != (self.kinematics.n_feet,):
            names = self.kinematics.contact_names
            raise ValueError(f"contact plan needs {len(names)} flags ({names}), got shape {plan.shape}")
        return plan

    def _read_joints(self, measurement: Measurement) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Take the joint readings, holding the last good value of any non-finite one. Returns,
        per foot, whether its leg's positions, velocities and efforts are all good."""
        try:  # one copy of all three (the caller may refill its arrays in place; these are the "last good" values)
            readings = np.array((measurement.joint_positions, measurement.joint_velocities, measurement.joint_efforts), float)
        except ValueError:  # ragged: the shapes are checked below
            readings = None
        # All finite when the sum of squares is (a huge but finite reading overflows it: checked one by one below).
        if readings is not None and readings.shape == (3, self._dofs) and math.isfinite(np.vdot(readings, readings)):
            self._positions, self._velocities, self._efforts = readings[0], readings[1], readings[2]  # views of the copy
            return self._all_feet, self._all_feet, self._all_feet
        for name, value in (
            ("positions", measurement.joint_positions),
            ("velocities", measurement.joint_velocities),
            ("efforts", measurement.joint_efforts),
        ):
            value = np.asarray(value, float)
            if value.shape != (self._dofs,):
                raise ValueError(f"joint {name} need shape ({self._dofs},), got {value.shape}")
        positions, velocities, efforts = readings
        ok, held = [], []
        for name, value, last, fault in (
            ("position", positions, self._positions, Fault.JOINT_POSITION_INVALID),
            ("velocity", velocities, self._velocities, Fault.JOINT_VELOCITY_INVALID),
            ("effort", efforts, self._efforts, Fault.JOINT_EFFORT_INVALID),
        ):
            finite = np.isfinite(value)
            if not finite.all():
                bad = [self.description.joint_names[j] for j in np.flatnonzero(~finite)]
                self.monitor.flag(fault, f"non-finite joint {name} at {bad}: last good value held")
            ok.append(~(self._leg_mask & ~finite).any(axis=1))
            held.append(np.where(finite, value, last))
        self._positions, self._velocities, self._efforts = held
        position_ok, velocity_ok, effort_ok = ok
        return position_ok, velocity_ok & position_ok, effort_ok & position_ok

    def _detect_contacts(
        self, measurement: Measurement, effort_ok: np.ndarray, use_efforts: bool, plan: np.ndarray | None, dt: float
    ) -> np.ndarray:
        """Ground forces per foot (world) and the contact flags used by this update."""
        if use_efforts:
            valid = effort_ok
            # the legs' wrenches' forces (valid legs), a "pulling" foot carrying nothing (the ground pushes, never pulls)
            # unless pulling_forces, and the standing share of force_max_speed (a compiled kernel)
            kernels.effort_forces(self.kinematics.foot_wrenches, valid, self.kinematics.foot_velocities, self.filter.x,
                                  self.config.force_max_speed, self.config.pulling_forces, self._forces)
        else:
            given = measurement.contact_forces
            measured = np.asarray(given, float) if given is not None else np.full(len(effort_ok), np.nan)
            valid = np.isfinite(measured)
            if measurement.contact_forces is not None and not valid.all():
                self.monitor.flag(Fault.CONTACT_FORCE_INVALID, f"non-finite contact forces {measured}: contact flags held")
            self._forces[valid] = 0.0
            self._forces[valid, 2] = measured[valid]
        detected = self.detector.update(self._forces[:, 2], dt, None if valid is self._all_feet else valid)
        return detected if plan is None else plan

    # --- state ----------------------------------------------------------------------------
    def _base_attitude(self, gyro: Sequence[float]) -> tuple[so3.Quaternion, so3.Matrix3, so3.Vector3]:
        """The base orientation (quaternion and matrix) from the orientation filter's IMU
        orientation, and the base angular velocity (base frame) from the bias-corrected gyro."""
        quaternion = so3.quat_multiply_floats(self.orientation.quaternion_floats, self._imu_to_base)
        bx, by, bz = self.orientation.gyro_bias_floats
        omega = so3.rotate(self._imu_rotation, (gyro[0] - bx, gyro[1] - by, gyro[2] - bz))
        return quaternion, so3.quat_to_matrix_floats(quaternion), omega

    def _led_omega(self, omega: so3.Vector3, dt: float) -> so3.Vector3:
        """Config ``omega_lead``: the base rate ``omega`` plus ``omega_lead`` times its low-passed
        derivative (a first-order prediction over the sensor's latency)."""
        last, self._omega_last = self._omega_last, omega
        if last is None or dt <= 0.0:
            return omega
        alpha = dt / (self.config.omega_lead_time + dt)
        self._omega_rate = tuple(r + alpha * ((w - w0) / dt - r) for r, w, w0 in zip(self._omega_rate, omega, last))
        lead = self.config.omega_lead
        return (omega[0] + lead * self._omega_rate[0], omega[1] + lead * self._omega_rate[1], omega[2] + lead * self._omega_rate[2])

    def _world_acceleration(self, base_rotation: so3.Matrix3, accel: Sequence[float]) -> so3.Vector3:
        """The IMU's acceleration in the world (its specific force rotated to world, plus gravity)."""
        ax, ay, az = so3.rotate(base_rotation, so3.rotate(self._imu_rotation, accel))
        gx, gy, gz = self._gravity
        return (ax + gx, ay + gy, az + gz)

    def _leg_accelerations(
        self, rotation: so3.Matrix3, omega: so3.Vector3, accel: list[float] | None, dt: float
    ) -> np.ndarray:
        """Config ``force_inertia``: update the low-passed joint accelerations (``self._joint_acceleration``,
        the derivative of the joint velocities' first-order low-pass) and return the base's
        acceleration (base frame: the origin's linear acceleration without gravity, then the angular
        acceleration), low-passed alike: the accelerometer's specific force (bias removed) rotated to
        the world plus gravity, moved from the IMU to the base origin, and the gyro differentiated.
        No accelerometer: the linear part is taken as zero (the quasi-static estimate's assumption).
        One compiled call (:func:`giwbc.estimation.kernels.leg_accelerations`)."""
        tau = self.config.force_inertia_time
        alpha, rate = (dt / (tau + dt), 1.0 / (tau + dt)) if dt > 0.0 else (1.0, 0.0)
        if accel is not None:
            bx, by, bz = self._accel_bias
            accel = (accel[0] - bx, accel[1] - by, accel[2] - bz)
        kernels.leg_accelerations(
            self._velocities, self._joint_velocity_lp, self._joint_acceleration, self._base_motion_lp, not self._inertia_started,
            dt <= 0.0, omega, (0.0, 0.0, 0.0) if accel is None else accel, accel is not None, rotation, self._imu_rotation,
            self._imu_offset_base, self._gravity, alpha, rate, self._base_acceleration,
        )
        self._inertia_started = True
        return self._base_acceleration

    def _rolling_velocity_trust(self, loads: list[float], dt: float) -> list[float]:
        """Config ``roll_velocity_rate``: each stance foot's confidence for its velocity row, divided by
        ``1 + (rate / roll_velocity_rate)^2`` (so its noise variance grows by that squared), ``rate``
        the larger of the sole's angular rate now and low-passed (``foot_roll_time``): the instant
        catches a roll's start, the low-pass holds the trust down through its end."""
        alpha = dt / (self.config.foot_roll_time + dt) if dt > 0.0 else 1.0
        kernels.rolling_trust(self.kinematics.foot_angular_velocities, tuple(loads), self._velocity_rate2, alpha,
                              1.0 / self.config.roll_velocity_rate**2, self._trust)
        return self._trust.tolist()

    def _still_feet(self, loads: list[float], dt: float) -> list[float]:
        """Stance confidences less for a turning foot (module doc, point 2): a sole that rolls on
        an edge or point, rocks or slips is neither flat nor a still point (its frame moves). The
        squared rate is low-passed (``foot_roll_time``): gyro and encoder noise alone is no turn."""
        alpha = dt / (self.config.foot_roll_time + dt) if dt > 0.0 else 1.0
        kernels.still_feet(self.kinematics.foot_angular_velocities, tuple(loads), self._rate2, self._still_since, self._time, alpha,
                           1.0 / self.config.foot_roll_rate**2, self.config.contact_min_confidence, self._trust)
        return self._trust.tolist()

    def _kinematics_lists(self) -> tuple[list, list]:
        """This update's foot wrenches and rotations as Python floats (converted once, on first use:
        the flat-feet reference reads them per foot; the compiled steps read the arrays)."""
        if self._foot_lists is None:
            kin = self.kinematics
            self._foot_lists = (kin.foot_wrenches.tolist(), kin.foot_rotations.tolist())
        return self._foot_lists

    def _pull_to_ground(self, flags: list[bool], still: list[float], dt: float) -> None:
        """Config ``ground_pull``: the height states (IMU and every foot) shifted together toward the
        stance feet standing on the flat ground, each foot weighted by how still it is (a rolling
        foot's sole centre is above the ground). The filter measures heights only relative to each
        other, so a common shift is its unobservable direction: nothing it measures is contradicted."""
        kernels.pull_to_ground(self.filter.x, tuple(flags), tuple(still), self.config.ground_pull, dt / self.config.ground_pull_time)

    def _pivot_velocity(self) -> np.ndarray:
        """Per foot, the velocity (relative to a non-translating IMU, world axes) of its centre of
        pressure, the point of the sole that stays put when the foot rolls on an edge or a point
        (config ``pivot_velocity``): ``v_centre + w_foot x r``, ``r`` the CoP from the sole centre on
        the sole plane, from the leg's wrench, clamped to the sole's half sizes (a compiled kernel)."""
        kin = self.kinematics
        kernels.pivot_velocities(kin.foot_wrenches, kin.foot_rotations, kin.foot_angular_velocities, kin.foot_velocities,
                                 self._sole_half_array, self._pivot_velocities)
        return self._pivot_velocities

    def _stance_confidence(self, flags: list[bool]) -> list[float]:
        """Per foot: 0 in swing, else its load confidence, at least ``contact_min_confidence``."""
        least = self.config.contact_min_confidence
        return [max(load, least) if standing else 0.0 for load, standing in zip(self.detector.confidence_floats(), flags)]

    def _initialize_filter(self, stance: np.ndarray) -> None:
        """Feet on the ground (all of them, or those in stance) at rest; xy from the config."""
        c, kin = self.config, self.kinematics
        on_ground = stance if stance.any() else np.ones_like(stance)
        imu = np.empty(3)
        imu[:2] = np.asarray(c.initial_base_xy, float) + kin.imu_offset[:2]
        imu[2] = c.initial_ground_height - float(np.mean(kin.foot_positions[on_ground, 2]))
        self.filter.initialize(imu, imu + kin.foot_positions)

    def _initial_estimate(self) -> Estimate:
        """Placeholder before the first good measurement: the description's default pose."""
        q = self.description.default_configuration()
        n = self.kinematics.n_feet
        base = BaseState(q[:3].copy(), q[3:7].copy(), np.zeros(3), np.zeros(3))
        v = np.zeros(self.kinematics.model.nv)
        covariance = np.eye(6) * UNKNOWN_VARIANCE
        return Estimate(float("nan"), base, q, v, np.ones(n, bool), np.ones(n), np.zeros((n, 3)), covariance, np.zeros(3),
                        FaultReport(), initialized=False, ready=False)

    def _hold(self) -> Estimate:
        """The last good estimate, carrying this update's faults."""
        self._estimate = replace(self._estimate, faults=self.monitor.finish(held=True))
        return self._estimate

    def _make_estimate(
        self, rotation: so3.Matrix3, quaternion: so3.Quaternion, omega_local: so3.Vector3, stance: np.ndarray,
        confidence: np.ndarray, faults: FaultReport,
    ) -> Estimate:
        kf = self.filter
        q, v, state = np.empty(self._nq), np.empty(self._nv), np.empty(13)
        kernels.assemble_state(kf.x, self.kinematics.imu_offset, rotation, quaternion, omega_local, self._positions,
                               self._velocities, q, v, state)
        base = BaseState(state[0:3], state[3:7], state[7:10], state[10:13])  # views of this estimate's own array
        return Estimate(self._time, base, q, v, stance, confidence, self._forces.copy(), kf.base_covariance(),
                        np.array(self.orientation.gyro_bias_floats), faults, ready=self._ready)


def _rotated(q: Sequence[float], rotation_vector: Sequence[float]) -> so3.Quaternion:
    """``q`` turned by a small body-frame rotation vector."""
    rx, ry, rz = rotation_vector
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    s = 0.5 if angle < 1e-8 else math.sin(0.5 * angle) / angle
    return so3.quat_multiply_floats(q, (s * rx, s * ry, s * rz, math.cos(0.5 * angle)))
