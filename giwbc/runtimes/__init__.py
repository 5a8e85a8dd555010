"""Runtimes: the ``gymnasium.Env`` objects that run a Task, and their rates and sim-to-real knobs."""

from giwbc.runtimes.rates import RateError, Rates
from giwbc.runtimes.sim2real import PushConfig, SimToReal
from giwbc.runtimes.simulated import SimulatedRobot, SimulatedRuntime, StepTimings

__all__ = ["PushConfig", "RateError", "Rates", "SimToReal", "SimulatedRobot", "SimulatedRuntime", "StepTimings"]
