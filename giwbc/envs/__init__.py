"""Registered environments: ``gymnasium.make("giwbc/<Id>")`` after ``import giwbc.envs``
(or, with nothing imported, ``gymnasium.make("giwbc.envs:giwbc/<Id>")``).

Each id is a factory (:mod:`giwbc.envs.factories`, imported by gymnasium on the first
``make``) building a Task and a :class:`~giwbc.runtimes.simulated.SimulatedRuntime` over a robot description.
Keyword arguments of ``gymnasium.make`` reach the factory: rates, ``real_time_factor``,
``render_mode``, ``sim2real`` (a :class:`SimToReal` or a dict of its fields), and

* ``engine``: ``"mujoco"`` (default), ``"pybullet"``, or a per-episode random choice
  (an :class:`~giwbc.randomization.EngineChoice` or ``{"mujoco": 0.5, "pybullet": 0.5}``);
* ``randomization``: domain randomization applied at every reset: a config dict, a TOML path,
  ``"default"`` (the robot's ``randomization.toml``), a RandomizationConfig or a DomainRandomizer;
* ``engine_options``: constructor keywords per engine (``{"pybullet": {"solver_iterations": 50}}``);
* ``model``: a modified ``mujoco.MjModel`` to simulate instead of the description's (MuJoCo
  only; it is copied);

and the task's own options. Every option is JSON-friendly in its plain form, so a policy's
metadata can carry it.
"""

from __future__ import annotations

import gymnasium

NAMESPACE = "giwbc"
CARTPOLE_BALANCE = "giwbc/CartPoleBalance-v0"
CARTPOLE_SWING_UP = "giwbc/CartPoleSwingUp-v0"
G1_BALANCE = "giwbc/G1Balance-v0"
G1_WALK = "giwbc/G1Walk-v0"

# id -> (entry point, max_episode_steps); each entry point is a factory of giwbc.envs.factories.
ENVIRONMENTS: dict[str, tuple[str, int]] = {
    CARTPOLE_BALANCE: ("giwbc.envs.factories:cartpole_balance", 500),
    CARTPOLE_SWING_UP: ("giwbc.envs.factories:cartpole_swing_up", 1000),
    G1_BALANCE: ("giwbc.envs.factories:g1_balance", 1000),
    G1_WALK: ("giwbc.envs.factories:g1_walk", 1000),
}

# What gymnasium.make options go to the runtime rather than the task (a deployment drops them too).
RUNTIME_OPTIONS = ("model", "plant", "plant_redraws", "controller_rate", "real_time_factor", "render_mode", "sim2real", "render_size",
                   "engine", "engine_options", "randomization")


def register_envs() -> None:
    """Register every giwbc id with gymnasium (idempotent)."""
    for env_id, (entry_point, max_steps) in ENVIRONMENTS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point, max_episode_steps=max_steps)


register_envs()

__all__ = ["CARTPOLE_BALANCE", "CARTPOLE_SWING_UP", "ENVIRONMENTS", "G1_BALANCE", "G1_WALK", "NAMESPACE", "RUNTIME_OPTIONS", "register_envs"]
