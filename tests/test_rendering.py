"""A machine with no GL library runs everything but rendering; rendering finds its backend when it starts.

The "no GL library" machine is made with a ``sitecustomize`` on ``PYTHONPATH`` that refuses to
import PyOpenGL (the only way MuJoCo's Python side reaches ``libEGL``/``libOSMesa``), so child
processes, including the backend probes, see the same machine.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from giwbc.runtimes.rendering import OFFSCREEN_BACKENDS, probe_backend

ROOT = Path(__file__).resolve().parents[1]
POLICY = ROOT / "policies" / "g1_balance_residual.onnx"

NO_GL = textwrap.dedent(
    """
    import sys
    from importlib.abc import MetaPathFinder

    class _NoGL(MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "OpenGL" or name.startswith("OpenGL."):
                raise ImportError("no GL library on this machine (test)")
            return None

    sys.meta_path.insert(0, _NoGL())
    """
)


@pytest.fixture
def no_gl_env(tmp_path) -> dict[str, str]:
    """Environment variables for a child process on a machine without any GL library."""
    (tmp_path / "sitecustomize.py").write_text(NO_GL)
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), str(ROOT)])
    return env


def _run(code: str, env: dict[str, str], timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout,
                          cwd=ROOT)


def test_the_no_gl_machine_has_no_backend(no_gl_env) -> None:
    """The fixture really hides GL: no backend probes successfully there."""
    code = ("import json; from giwbc.runtimes.rendering import probe_backend, OFFSCREEN_BACKENDS; "
            "print(json.dumps({b: probe_backend(b) for b in OFFSCREEN_BACKENDS}))")
    result = _run(code, no_gl_env)
    assert result.returncode == 0, result.stderr[-2000:]
    reasons = json.loads(result.stdout.strip().splitlines()[-1])
    assert set(reasons) == set(OFFSCREEN_BACKENDS)
    assert all(reason and "no GL library" in reason for reason in reasons.values()), reasons


def test_demo_and_env_import_paths_need_no_gl(no_gl_env) -> None:
    """What `make demo` and the envs import, build and step works with no GL library, and loads none."""
    code = textwrap.dedent(
        """
        import json, sys
        import numpy as np, gymnasium
        import giwbc.apps.cli, giwbc.apps.demo, giwbc.envs, giwbc.apps.deploy, giwbc.apps.evaluation, giwbc.apps.sim_to_sim
        from giwbc.apps.cli import run_pd_hold
        summary = run_pd_hold("g1", 0.1)
        env = gymnasium.make("giwbc/G1Balance-v0")
        obs, _ = env.reset(seed=0)
        obs, *_ = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        print(json.dumps({"gl": "OpenGL" in sys.modules, "finite": bool(np.isfinite(obs).all()),
                          "height": summary.min_base_height}))
        """
    )
    result = _run(code, no_gl_env)
    assert result.returncode == 0, result.stderr[-3000:]
    out = json.loads(result.stdout.strip().splitlines()[-1])
    assert out["gl"] is False and out["finite"] is True
    assert out["height"] > 0.5  # the G1 was simulated standing, not a crash with a default value


def test_video_without_gl_is_one_line_error_before_any_work(no_gl_env, tmp_path) -> None:
    """`giwbc play --video` on such a machine: exit 2, one line naming the package, no traceback, no file."""
    video = tmp_path / "out.mp4"
    result = subprocess.run([sys.executable, "-m", "giwbc.apps.cli", "play", "--policy", str(POLICY), "--max-steps", "2",
                             "--video", str(video)], env=no_gl_env, capture_output=True, text=True, timeout=300,
                            cwd=ROOT)
    assert result.returncode == 2, result.stderr[-3000:]
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert "libosmesa6" in lines[0] and "libegl1" in lines[0]
    assert not video.exists() and "episode" not in result.stdout


def test_unknown_backend_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown offscreen GL backend"):
        probe_backend("glx")


@pytest.mark.parametrize("backend", sorted(OFFSCREEN_BACKENDS))
def test_play_writes_a_video_of_the_robot(tmp_path, backend) -> None:
    """With the backend present, `giwbc play --video` writes one frame per step plus the reset, showing a scene."""
    reason = probe_backend(backend)
    if reason is not None:
        pytest.skip(f"{backend} is not usable here ({reason}): install {OFFSCREEN_BACKENDS[backend]}")
    imageio = pytest.importorskip("imageio.v2", reason="the video extra (imageio) is not installed")
    pytest.importorskip("imageio_ffmpeg", reason="the video extra (imageio-ffmpeg) is not installed")
    video = tmp_path / "play.mp4"
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"} | {"MUJOCO_GL": backend}
    result = subprocess.run([sys.executable, "-m", "giwbc.apps.cli", "play", "--policy", str(POLICY), "--max-steps", "5",
                             "--video", str(video), "--json"], env=env, capture_output=True, text=True, timeout=300,
                            cwd=ROOT)
    assert result.returncode == 0, result.stderr[-3000:]
    assert json.loads(result.stdout.strip().splitlines()[-1])["video"] == str(video)
    frames = imageio.mimread(video)
    assert len(frames) == 6  # the reset frame and one per step
    first = frames[0]
    assert first.shape == (480, 640, 3)
    # A rendered scene (floor, robot, sky), not a blank buffer: many distinct colours.
    assert len({tuple(p) for p in first.reshape(-1, 3)[::97]}) > 20
