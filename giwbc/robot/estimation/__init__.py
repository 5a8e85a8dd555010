"""Building blocks of the base state estimator (:mod:`giwbc.robot.estimator` puts them together):
SO(3) helpers, the IMU orientation filter, leg kinematics, the leg Kalman filter, contact
detection, fault bookkeeping, and a MuJoCo push scenario to evaluate the result against truth."""
