"""Runtimes: the ``gymnasium.Env`` objects that run a Task, and their rates and sim-to-real knobs."""

from giwbc.runtimes.engines import EnginePool, engine_of
from giwbc.tasks.rates import RateError, Rates
from giwbc.runtimes.phases import StartupConfig
from giwbc.runtimes.realtime import RealtimeRuntime, RunResult
from giwbc.runtimes.sim2real import PushConfig, SimToReal
from giwbc.runtimes.simulated import SimulatedRobot, SimulatedRuntime, StepTimings

__all__ = ["EnginePool", "PushConfig", "RateError", "Rates", "RealtimeRuntime", "RunResult", "SimToReal", "SimulatedRobot", "SimulatedRuntime", "StartupConfig", "StepTimings", "engine_of"]
