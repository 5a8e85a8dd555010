"""Base state estimation for robots that do not measure their base (hardware, noisy simulation).

:class:`StateEstimator` (:mod:`~giwbc.estimation.estimator`) fuses the IMU and the leg kinematics
of the feet in contact: the IMU orientation filter (:mod:`~giwbc.estimation.orientation`), leg
kinematics (:mod:`~giwbc.estimation.kinematics`), start-up standstill calibration and
zero-velocity updates (:mod:`~giwbc.estimation.calibration`), the leg Kalman filter
(:mod:`~giwbc.estimation.kalman`), contact detection (:mod:`~giwbc.estimation.contacts`), the held
heading of stance feet (:mod:`~giwbc.estimation.headings`) and fault
bookkeeping (:mod:`~giwbc.estimation.faults`), with SO(3) helpers in :mod:`~giwbc.robot.so3`.
:mod:`~giwbc.estimation.evaluation` runs a MuJoCo push scenario to score it against truth.
"""
