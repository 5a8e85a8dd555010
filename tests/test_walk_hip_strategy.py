"""The walker's hip strategy (``WalkerConfig.hip_roll_gain``): after a lateral push while walking on
the estimate, the pelvis rolls into the DCM error and the stance ankle roll stays inside the
deployment's soft limits where the preset walker's passes them (selection seed 508: 50 N to the
right, 1.82 s into the episode). Off by default, and bit for bit the walker without it."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import giwbc.envs  # noqa: F401  (registers the ids)
from giwbc.locomotion.walker_config import DEPLOYMENT_OPTIONS, WalkerConfig

SEED = 508
HIP = {"hip_roll_gain": 4.0, "hip_roll_max": 0.2}  # rad per m of lateral DCM error, rad
# The estimator the seed was selected on: ANY_FEET without issue 41's foot-force terms (inertia, no pull,
# moving-foot gate) and rolling-foot down-weighting. With them the preset walker recovers seed 508's push
# on its own (measured: no soft-limit end), so the scenario keeps the estimate it was chosen for; so too
# without the base rate's lead (omega_lead, issue 41: with it the preset walker walks seed 508 on as well).
SELECTED_ESTIMATOR = {
    "config": {"force_inertia": False, "pulling_forces": True, "force_max_speed": 0.0, "roll_velocity_rate": 0.0,
               "omega_lead": 0.0},
}



def _scenario(force: float, kwargs: dict) -> dict:
    """The walking episode these seeds were chosen on, pinned: the evaluate walk protocol's before its 3 s settle
    window (push schedule drawn to 60 s, 3.8 s episodes), so the random draws stay those of the tuning. It is a
    scenario for the ankle-roll checks, not a push-recovery score (that is ``giwbc evaluate --protocol walk``)."""
    commands = {"vx": [0.1, 0.4], "vy": [-0.1, 0.1], "yaw_rate": [-0.3, 0.3], "standing": 0.0, "interval": [4.8, 4.8], "horizon": 4.8}
    sim2real = {**kwargs.get("sim2real", {}), "pushes": {"interval": [1.8, 2.0], "duration": 0.2, "force": [force, force]}}
    return {**kwargs, "sim2real": sim2real, "commands": commands, "max_episode_steps": 190}

def _episode(extra: dict) -> tuple[bool, np.ndarray, np.ndarray, float]:
    """(terminated, per ankle roll: lowest and highest angle and the soft limit's margin, the largest |pelvis roll reference|)."""
    kwargs = {
        "residuals": ["step"], "walker": {**DEPLOYMENT_OPTIONS, **extra}, "initial_joint_noise": 0.0,
        "wbc_options": {"joint_limits": True, "joint_limit_margin": 0.04}, "joint_limit_margin": 0.02,
        "sim2real": {"estimator": SELECTED_ESTIMATOR}, "randomization": {"imu_profile": "ahrs", "parameters": []},
    }  # fmt: skip
    env = gymnasium.make("giwbc/G1Walk-v0", **_scenario(50.0, kwargs))
    task = env.unwrapped.task
    names = task.description.joint_names
    joints = [names.index("left_ankle_roll_joint"), names.index("right_ankle_roll_joint")]
    env.reset(seed=SEED)
    zero = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    low, high = np.zeros(2), np.zeros(2)
    roll = 0.0
    terminated = truncated = False
    while not (terminated or truncated):
        _, _, terminated, truncated, _ = env.step(zero)
        q = task.robot.joint_positions()[joints]
        low, high = np.minimum(low, q), np.maximum(high, q)
        rotation = task.walker.balance.base_task.reference.rotation
        roll = max(roll, abs(float(np.arctan2(rotation[2, 1], rotation[2, 2]))))
    env.close()
    inside = np.minimum(low - task._soft_lower[joints], task._soft_upper[joints] - high)
    return terminated, inside, roll


@pytest.mark.slow
def test_the_hip_strategy_keeps_the_stance_ankle_roll_inside_its_soft_limit():
    ended, inside, roll = _episode({})
    assert ended and inside.min() < 0.0 and roll == 0.0  # the preset: an ankle roll past the deployment soft limit, pelvis level
    ended, inside, roll = _episode(HIP)
    assert not ended and inside.min() > 0.01  # walked on, both ankle rolls inside with a margin
    assert 0.05 < roll <= HIP["hip_roll_max"] + 1e-9  # the pelvis did roll, within the bound


@pytest.mark.parametrize(
    "options",
    [{"hip_roll_gain": -1.0}, {"hip_roll_gain": float("nan")}, {"hip_roll_max": 0.0}, {"hip_roll_max": 0.6},
     {"hip_gate": (0.08, 0.03)}, {"hip_gate": (-0.01, 0.05)}],
)
def test_bad_hip_strategy_options_are_refused(options):
    with pytest.raises(ValueError, match="hip_"):
        WalkerConfig(**options)


def _joint_trajectory(residuals: list[str], action: dict[str, float], walker: dict) -> tuple[np.ndarray, bool]:
    """Seed 508's episode with a constant action (entries by name, others 0): joint positions per agent step, and whether it fell."""
    kwargs = {
        "residuals": residuals, "walker": {**DEPLOYMENT_OPTIONS, **walker}, "initial_joint_noise": 0.0,
        "wbc_options": {"joint_limits": True, "joint_limit_margin": 0.04}, "joint_limit_margin": 0.02,
        "sim2real": {"estimator": SELECTED_ESTIMATOR}, "randomization": {"imu_profile": "ahrs", "parameters": []},
    }  # fmt: skip
    env = gymnasium.make("giwbc/G1Walk-v0", **_scenario(50.0, kwargs))
    task = env.unwrapped.task
    names = task.action_names()
    constant = np.array([action.get(name, 0.0) for name in names], dtype=env.action_space.dtype)
    env.reset(seed=SEED)
    rows, terminated, truncated = [], False, False
    while not (terminated or truncated):
        _, _, terminated, truncated, _ = env.step(constant)
        rows.append(task.robot.joint_positions().copy())
    env.close()
    return np.array(rows), terminated


@pytest.mark.slow
def test_the_hip_residual_is_the_hip_strategy_gain():
    """The ``hip`` block's action times its scale (8 rad/m) is added to the walker's hip gain: a
    constant 0.5 is the hip strategy at 4 rad/m bit for bit (so it walks on past seed 508's push),
    and zero is the walker alone."""
    hip, hip_fell = _joint_trajectory(["step", "hip"], {"hip/roll_gain": 0.5}, {})
    strategy, strategy_fell = _joint_trajectory(["step"], {}, {"hip_roll_gain": 4.0})
    assert np.array_equal(hip, strategy) and not hip_fell and not strategy_fell
    zero, zero_fell = _joint_trajectory(["step", "hip"], {}, {})
    alone, alone_fell = _joint_trajectory(["step"], {}, {})
    assert np.array_equal(zero, alone) and zero_fell and alone_fell


def test_the_hip_residual_must_be_finite():
    from giwbc.locomotion.walker import WalkingController  # noqa: F401  (the mixin's owner)
    from giwbc.locomotion.residuals import Residuals

    with pytest.raises(ValueError, match="hip residual"):
        Residuals.set_hip_residual(object.__new__(Residuals), float("nan"))
