"""giwbc's one error hierarchy: everything it raises on purpose derives from :class:`GiwbcError`.

Callers (the ``giwbc`` command line first) catch ``GiwbcError`` once and print one line; each
class also derives from the builtin a Python user would expect (``ValueError`` for bad input or
configuration, ``RuntimeError`` for a state that forbids the call), and a CAN protocol error is
also a ``can.CanError``, so existing ``except`` clauses keep working.

```
GiwbcError
├── ConfigError (ValueError)          bad input or configuration; the message names the problem
│   ├── RobotDescriptionError         robot.toml / URDF
│   │   └── CollisionError            a [[collision]] table
│   ├── MissingFileError (FileNotFoundError)  a file the user named that does not exist
│   ├── HardwareConfigError           hardware.toml
│   │   └── BusCapacityError          a bus plan beyond its bandwidth
│   ├── RandomizationError            randomization config
│   ├── RateError                     agent / controller / physics rates
│   ├── PolicyFormatError             a policy file that is not a giwbc policy
│   ├── ProtocolConfigError           motors a protocol cannot drive together
│   ├── CommandValueError             a command that cannot be encoded (NaN)
│   ├── NonFiniteCommand              NaN/inf in a command: never sent
│   └── InvalidActionError            an action outside the Task's space
├── CanProtocolError (can.CanError)     a received frame that is not a valid reply
│   ├── FrameLengthError, UnknownMotorError, CorruptFrameError
├── UnavailableError (RuntimeError)   asked for what this robot or machine cannot give
│   ├── NotMeasuredError              a quantity a real robot does not measure
│   ├── BaseStateUnavailable          a CAN robot without an estimator
│   └── RenderingUnavailableError     no offscreen OpenGL library
├── WorkerLostError (RuntimeError)    a distributed worker died and its work could not be retried
├── EstimatorCalibrationError (RuntimeError)  a simulated start-up calibration that never saw a standstill
├── DeployError (RuntimeError)        a deployment that cannot start (exit code 2)
└── DdsLinkError (RuntimeError)       the DDS link cannot carry commands to the robot (no reader, another writer)
```
"""

from __future__ import annotations

import can


class GiwbcError(Exception):
    """Base of every error giwbc raises on purpose."""


class ConfigError(GiwbcError, ValueError):
    """Bad input or configuration; the message names the file, entry or value at fault."""


class RobotDescriptionError(ConfigError):
    """A robot description is missing, malformed or inconsistent with its model."""


class PlantMismatchError(RobotDescriptionError):
    """A simulated plant (an MJCF file, an MjModel, a variant) that does not fit the robot description; the message names the element."""


class CollisionError(RobotDescriptionError):
    """A collision table is malformed or cannot be fitted (the description loader re-raises it with the file)."""


class MissingFileError(ConfigError, FileNotFoundError):
    """A file the user named (a checkpoint, a policy, a plan) that does not exist."""


class HardwareConfigError(ConfigError):
    """A hardware plan is malformed or cannot work; the message names the file and the problem."""


class BusCapacityError(HardwareConfigError):
    """A bus plan needs more bandwidth than allowed."""


class RandomizationError(ConfigError):
    """An invalid randomization config: unknown parameter, link or joint, or bad distribution."""


class RateError(ConfigError):
    """Rates that do not divide into each other, or are not positive."""


class PolicyFormatError(ConfigError):
    """An ONNX file that is not a giwbc policy, or does not match the environment it names."""


class ProtocolConfigError(ConfigError):
    """The motors given to a protocol cannot work together (bad id, ambiguous replies, bad variant)."""


class CommandValueError(ConfigError):
    """A command cannot be encoded at all (NaN); out-of-range values are clamped instead."""


class NonFiniteCommand(ConfigError):
    """A command with NaN or infinite entries (from a policy or controller): never sent."""


class InvalidActionError(ConfigError):
    """An action with the wrong shape or a NaN/inf entry; raised before anything changes."""


class CanProtocolError(GiwbcError, can.CanError):
    """A received frame is not a valid reply from a configured motor."""


class FrameLengthError(CanProtocolError):
    """The frame's payload length fits no reply variant expected for it."""


class UnknownMotorError(CanProtocolError):
    """The frame is not addressed from a motor configured on this bus (unknown id, foreign frame)."""


class CorruptFrameError(CanProtocolError):
    """The frame is addressed correctly but its content cannot be a reply (or the input is not bytes)."""


class UnavailableError(GiwbcError, RuntimeError):
    """Asked for something this robot or this machine cannot provide."""


class NotMeasuredError(UnavailableError):
    """A quantity a real robot does not measure (base pose/twist, link poses, contact wrenches)."""


class BaseStateUnavailable(UnavailableError):
    """The CAN robot measures no base state: attach an estimator."""


class RenderingUnavailableError(UnavailableError):
    """No OpenGL library for offscreen rendering: the message says what to install."""


class WorkerLostError(GiwbcError, RuntimeError):
    """A distributed (Ray) worker, task or node died: its work is reported lost, never silently dropped."""


class EstimatorCalibrationError(GiwbcError, RuntimeError):
    """A simulated runtime's state estimator did not calibrate: the held robot never stood still."""


class DeployError(GiwbcError, RuntimeError):
    """A deployment that cannot start: configuration, policy or hardware mismatch (exit code 2)."""


class DdsLinkError(GiwbcError, RuntimeError):
    """The DDS link cannot carry giwbc's commands to the robot: no reader of rt/lowcmd matched, or
    another writer (the robot's own locomotion service) commands it too."""
