"""Every registered giwbc environment: gymnasium's checker, vector envs, offscreen rendering."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from giwbc.envs import CARTPOLE_BALANCE, ENVIRONMENTS
from giwbc.runtimes.rendering import RenderingUnavailableError, find_offscreen_backend

ENV_IDS = sorted(ENVIRONMENTS)


@pytest.fixture(scope="module")
def g1_model():
    """The G1 MuJoCo model, built once (about 1.5 s); each env gets its own copy."""
    from giwbc.robot import load

    return load("g1").build_mujoco()


def make_kwargs(env_id: str, request: pytest.FixtureRequest, bitwise: bool = False) -> dict:
    """Options for ``gymnasium.make``: the prebuilt G1 model; with ``bitwise``, OSQP in the WBC
    (proxsuite 0.8.0 is reproducible only to ~1e-14 across processes; see test_env_g1)."""
    if "G1" not in env_id:
        return {}
    return {"model": request.getfixturevalue("g1_model"), **({"wbc_options": {"solver": "osqp"}} if bitwise else {})}


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_registered_and_passes_check_env(env_id: str, request: pytest.FixtureRequest) -> None:
    env = gymnasium.make(env_id, **make_kwargs(env_id, request))
    assert env.spec.max_episode_steps == ENVIRONMENTS[env_id][1]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the checker's warnings are failures here
        # Render modes are checked offscreen in test_rgb_array_rendering ("human" opens a window).
        check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_module_form_needs_no_import() -> None:
    """``gymnasium.make("giwbc.envs:giwbc/...")`` works in a fresh interpreter that imported nothing."""
    code = "import gymnasium; env = gymnasium.make('giwbc.envs:giwbc/CartPoleBalance-v0'); print(env.reset(seed=0)[0].shape)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "(5,)"


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_async_vector_env_matches_single_envs(env_id: str, request: pytest.FixtureRequest) -> None:
    kwargs = make_kwargs(env_id, request, bitwise=True)
    vector = gymnasium.vector.AsyncVectorEnv([lambda: gymnasium.make(env_id, **kwargs)] * 2)
    try:
        observations, _ = vector.reset(seed=[3, 4])
        actions = np.random.default_rng(0).uniform(-0.3, 0.3, (3, *vector.single_action_space.shape)).astype(np.float32)
        rewards = []
        for action in actions:
            observations, reward, *_ = vector.step(np.stack([action, action]))
            rewards.append(reward)
    finally:
        vector.close()
    assert observations.shape == (2, *vector.single_observation_space.shape)
    # Worker 0 ran exactly what a single env seeded 3 runs; worker 1 (seed 4) did not.
    single = gymnasium.make(env_id, **kwargs)
    single.reset(seed=3)
    for action in actions:
        expected, reward, *_ = single.step(action)
    assert observations[0].tobytes() == expected.tobytes() and rewards[-1][0] == reward
    assert observations[1].tobytes() != expected.tobytes()


RENDER_SCRIPT = textwrap.dedent(
    """
    import json, numpy as np, gymnasium, giwbc.envs
    from gymnasium.utils.passive_env_checker import env_render_passive_checker
    result = {}
    for env_id in %r:
        env = gymnasium.make(env_id, render_mode="rgb_array", render_size=(120, 160))
        env.reset(seed=0)
        env.step(env.action_space.sample() * 0)
        frame = env.render()
        env_render_passive_checker(env)
        result[env_id] = [list(frame.shape), str(frame.dtype), len(np.unique(frame.reshape(-1, 3), axis=0))]
        env.close()
        env.close()  # closing twice is allowed
    print(json.dumps(result))
    """
)


def test_rgb_array_rendering() -> None:
    """Offscreen frames are (H, W, 3) uint8 and show something; the backend is found when rendering starts."""
    try:
        find_offscreen_backend()
    except RenderingUnavailableError as error:
        pytest.skip(str(error))
    env_ids = [CARTPOLE_BALANCE] + [i for i in ENV_IDS if "G1" in i]
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    result = subprocess.run([sys.executable, "-c", RENDER_SCRIPT % (env_ids,)], env=env,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    frames = json.loads(result.stdout.strip().splitlines()[-1])
    for env_id in env_ids:
        shape, dtype, colours = frames[env_id]
        assert shape == [120, 160, 3] and dtype == "uint8"
        assert colours > 10, f"{env_id}: the frame has {colours} colours"


def test_render_without_mode_warns_and_returns_none() -> None:
    env = gymnasium.make(CARTPOLE_BALANCE).unwrapped
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None
    with pytest.raises(ValueError, match="render_mode"):
        gymnasium.make(CARTPOLE_BALANCE, render_mode="depth")
