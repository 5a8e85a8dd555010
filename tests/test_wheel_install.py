"""A non-editable install works: the wheel carries the robots and the policies, and an installed
giwbc, run outside the source tree, lists its robots, deploys the G1 on the emulator and plays a
shipped policy by name and by the path the docs write.

The wheel is built offline (no build isolation, no index) from a copy of the sources, and
installed with pip into a new venv outside the source tree whose site-packages links every
dependency of this interpreter's but giwbc itself (no download); the test checks that giwbc is
imported from the wheel's copy, not from the checkout.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import site
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Not copied from the source tree: environments, caches, build and run outputs (see .gitignore).
NOT_SOURCES = shutil.ignore_patterns(".venv", ".git", "runs", "build", "dist", ".mutation", "mutants", ".hypothesis",
                                     ".pytest_cache", "__pycache__", "*.pyc", "*.egg-info", "*.mcap", "*.mp4")
DATA_FOLDERS = ("robots", "policies")
OWN_ENTRY = re.compile(r"^(giwbc([-_.].*)?|__editable__[._]+giwbc.*|_?giwbc.*\.(pth|egg-link))$", re.IGNORECASE)


def run(command: list[str], cwd: Path, env: dict[str, str], timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def build_wheel(tmp_path: Path) -> Path:
    """The wheel of a copy of the sources (offline: no build isolation, no index)."""
    source = tmp_path / "src"
    shutil.copytree(ROOT, source, ignore=NOT_SOURCES, symlinks=True)
    out = tmp_path / "wheel"
    result = run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
                  "-w", str(out), str(source)], tmp_path, dict(os.environ))
    assert result.returncode == 0, result.stderr
    (wheel,) = out.glob("giwbc-*.whl")
    return wheel


def make_venv(tmp_path: Path, wheel: Path) -> Path:
    """A new venv holding the wheel, its dependencies linked from this interpreter's site-packages."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=60)
    python = venv / "bin" / "python"
    target = Path(run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path,
                      dict(os.environ)).stdout.strip())
    for packages in {Path(p) for p in [*site.getsitepackages(), sysconfig.get_paths()["purelib"]]}:
        for entry in packages.iterdir() if packages.is_dir() else ():
            if not OWN_ENTRY.match(entry.name) and not (target / entry.name).exists():
                (target / entry.name).symlink_to(entry)
    result = run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "-q", str(wheel)],
                 tmp_path, dict(os.environ))
    assert result.returncode == 0, result.stderr
    return venv


@pytest.mark.slow
def test_the_wheel_carries_robots_and_policies_and_runs_installed(tmp_path: Path) -> None:
    wheel = build_wheel(tmp_path)
    names = set(zipfile.ZipFile(wheel).namelist())
    for folder in DATA_FOLDERS:
        shipped = [p.relative_to(ROOT / folder).as_posix() for p in (ROOT / folder).rglob("*") if p.is_file()]
        assert shipped, folder
        missing = [f for f in shipped if f"giwbc/_data/{folder}/{f}" not in names]
        assert not missing, f"{folder} files not in the wheel: {missing}"
    for required in ("robots/g1/robot.toml", "robots/g1/hardware.toml", "robots/g1/randomization.toml",
                     "robots/cartpole/robot.toml", "robots/cartpole/cartpole.urdf", "policies/g1_balance_residual.onnx"):
        assert f"giwbc/_data/{required}" in names

    venv = make_venv(tmp_path, wheel)
    work = tmp_path / "work"  # outside the source tree: no robots/ or policies/ here
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "GIWBC_ROBOT_PATH", "VIRTUAL_ENV")}
    giwbc = str(venv / "bin" / "giwbc")

    where = run([str(venv / "bin" / "python"), "-c",
                 "import giwbc, giwbc.robot; print(giwbc.__file__); print(giwbc.robot.load('g1').folder)"], work, env)
    assert where.returncode == 0, where.stderr
    module, g1_folder = (Path(line) for line in where.stdout.split())
    assert venv in module.parents and ROOT not in module.parents  # the wheel's giwbc, not the checkout's
    assert venv in g1_folder.parents and g1_folder.name == "g1"

    robots = run([giwbc, "robots"], work, env)
    assert robots.returncode == 0, robots.stderr
    assert [line.split()[0] for line in robots.stdout.splitlines()[1:]] == ["cartpole", "g1"]
    assert robots.stderr == ""

    deploy = run([giwbc, "deploy", "--robot", "g1", "--emulate", "--seconds", "1", "--unpaced"], work, env, timeout=180)
    assert deploy.returncode == 0, deploy.stdout[-2000:] + deploy.stderr[-2000:]
    assert "clean run" in deploy.stdout and "(stood)" in deploy.stdout
    assert list((work / "runs").glob("deploy-g1-*.mcap"))

    for policy in ("g1_balance_residual", "policies/g1_walk_residual.onnx"):  # by name, and as the docs write it
        play = run([giwbc, "play", "--policy", policy, "--max-steps", "10", "--json", "--no-progress"], work, env)
        assert play.returncode == 0, play.stderr
        result = json.loads(play.stdout.strip().splitlines()[-1])
        assert result["lengths"] == [10] and result["endings"] == ["max steps"]
    missing = run([giwbc, "play", "--policy", "g1_nope"], work, env)
    assert missing.returncode == 2 and "shipped: g1_balance_residual, g1_walk_residual" in missing.stderr
