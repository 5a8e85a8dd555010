"""The run log: one MCAP file per run, JSON messages with a JSON schema per channel.

Channels (``log_time`` = ``publish_time`` = robot time of the cycle in ns since the run started):

=================  ==========================================================================
``/commands``      what went out: cycle, phase, frame kind, q_ref, v_ref, kp, kd, tau_ff
``/replies``       what came back: q, dq, tau, temperature, error codes, missing joints, late,
                   corrupt and unknown frames
``/estimator``     the IMU sample (quaternion x, y, z, w, angular velocity, acceleration, its
                   time) and the estimate from it: base position, quaternion, linear / angular
                   velocity, contacts, estimator faults (null without an estimator)
``/timing``        deadline slot, lateness, period, work and bus times (us), overrun flag
``/faults``        every fault: kind, message, cycle, time, joints
``/events``        phase changes and notes (start-up pose, clamped fields, shutdown)
``/walker``        with a walking controller, each control tick: its phase, stance side, steps,
                   time in phase, the swing foot's planned landing and target, the DCM and its
                   reference and error, the step adjustment, the WBC tick's outcome
                   (:mod:`giwbc.apps.deploy_walk_log`)
=================  ==========================================================================

A run's own fixed-size numeric channels (:class:`NumericChannel`, e.g. ``/walker``) are declared
when the writer is made; the loop hands over one float64 vector per record.

Arrays are in the order of the ``joint_names`` run metadata. :func:`read_log` loads a file back.

Who writes it: a logger process (:class:`RunLogWriter` starts it). The control loop only packs
each record in binary and hands a cycle's records over in one datagram; formatting, compression
and disk writes happen in the logger, on another CPU when there is one, never in the loop.
Faults and events are on disk before the logger reads on, and the logger finishes the file with
what it received if the control process dies. A :class:`LogExtension` adds channels derived from
the records in the logger process (the robot's 3D scene for Foxglove: ``giwbc.apps.foxglove``). Numbers are written with 6 significant digits;
non-finite values become ``null``.
"""

from giwbc.runlog.channels import WALKER_TOPIC, CycleRecorder, Field, NumericChannel
from giwbc.runlog.extension import LogExtension, RobotState
from giwbc.runlog.reader import RunLog, read_log
from giwbc.runlog.schema import SCHEMAS, json_floats
from giwbc.runlog.writer import RunLogWriter

__all__ = [
    "SCHEMAS", "WALKER_TOPIC", "CycleRecorder", "Field", "LogExtension", "NumericChannel", "RobotState", "RunLog", "RunLogWriter",
    "json_floats", "read_log",
]  # fmt: skip
