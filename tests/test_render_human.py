"""``render_mode="human"`` where no window can open is an exception at construction, never the end of
the process: MuJoCo's viewer, on a GLFW that cannot start, prints ``could not initialize GLFW`` and
exits the interpreter. Gymnasium's ``check_env`` with its defaults makes a "human" env of every
env, so on a headless machine it must raise (or pass), and the interpreter must live on."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import gymnasium
import pytest

import giwbc.envs  # noqa: F401  (registers the giwbc/ ids)
from giwbc.envs import ENVIRONMENTS
from giwbc.errors import RenderingUnavailableError
from giwbc.runtimes.rendering import display_problem, probe_window

CHECK_ENV = """
import json, sys
import gymnasium
from gymnasium.utils.env_checker import check_env
import giwbc.envs

results = {}
for env_id in sys.argv[1:]:
    for skip_render_check in (False, True):
        env = gymnasium.make(env_id)
        try:
            check_env(env.unwrapped, skip_render_check=skip_render_check)  # the defaults first
            results[f"{env_id} {skip_render_check}"] = "passed"
        except Exception as error:
            results[f"{env_id} {skip_render_check}"] = f"{type(error).__name__}: {error}"
        env.close()
try:
    gymnasium.make("giwbc/G1Walk-v0", render_mode="human").render()
    results["make human"] = "rendered"
except Exception as error:
    results["make human"] = f"{type(error).__name__}: {error}"
print(json.dumps(results))
"""
HEADLESS_REFUSAL = "RenderingUnavailableError: render_mode='human' needs a display for MuJoCo's viewer: no display"


def headless_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}


def test_check_env_with_its_defaults_raises_on_a_headless_machine_and_the_interpreter_lives_on() -> None:
    result = subprocess.run([sys.executable, "-c", CHECK_ENV, *ENVIRONMENTS], env=headless_env(), capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "could not initialize GLFW" not in result.stdout + result.stderr
    results = json.loads(result.stdout.strip().splitlines()[-1])
    for env_id in ENVIRONMENTS:
        with_defaults = results[f"{env_id} False"]
        assert with_defaults == "passed" or with_defaults.startswith(HEADLESS_REFUSAL), (env_id, with_defaults)
        assert results[f"{env_id} True"] == "passed", env_id  # all but the human window is a sound env
    assert results["make human"].startswith(HEADLESS_REFUSAL) and "rgb_array" in results["make human"]


def test_human_mode_is_refused_at_construction_without_a_display(monkeypatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if sys.platform.startswith("linux"):
        assert display_problem() is not None
        with pytest.raises(RenderingUnavailableError, match=r"^render_mode='human' needs a display .*no display \(DISPLAY"):
            gymnasium.make("giwbc/CartPoleBalance-v0", render_mode="human")
    env = gymnasium.make("giwbc/CartPoleBalance-v0")  # the other modes are unaffected
    assert env.unwrapped.metadata["render_modes"] == ["human", "rgb_array"] and env.unwrapped.render_mode is None
    env.close()


def test_a_display_glfw_cannot_open_is_found_by_a_child_process(monkeypatch) -> None:
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("DISPLAY", ":987")  # named, but no X server answers there
    if not sys.platform.startswith("linux"):
        pytest.skip("X11 displays are a Linux matter")
    assert display_problem() is None  # the environment alone cannot tell
    reason = probe_window()
    assert reason is not None and "GLFW cannot initialize" in reason and ":987" in reason
    with pytest.raises(RenderingUnavailableError, match=r"needs a display for MuJoCo's viewer: GLFW cannot initialize"):
        gymnasium.make("giwbc/G1Balance-v0", render_mode="human")


@pytest.mark.skipif(display_problem() is not None or probe_window() is not None, reason="no display to open a window on")
def test_human_mode_opens_mujocos_viewer_where_a_display_exists() -> None:
    script = ("import gymnasium, giwbc.envs\n"
              "env = gymnasium.make('giwbc/CartPoleBalance-v0', render_mode='human', real_time_factor=100.0)\n"
              "env.reset(seed=0)\n"
              "for _ in range(5): env.step(env.action_space.sample())\n"
              "assert env.unwrapped._viewer is not None\n"
              "env.close()\nprint('viewed')\n")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.strip().endswith("viewed"), result.stderr[-2000:]
