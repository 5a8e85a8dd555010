"""Progress bars: drawn on a terminal (a pseudo-terminal here), never on a pipe nor with
``--no-progress``; worker pools report each finished episode; PyBullet's start-up banner stays out
of a command's output."""

from __future__ import annotations

import io
import json
import os
import pty
import re
import subprocess
import sys
import threading
from pathlib import Path

from giwbc.apps.progress import Progress, wants_progress
from giwbc.apps.workers import map_jobs, quiet_banners

ROOT = Path(__file__).resolve().parents[1]
BAR = re.compile(r"(\d+(?:\.\d+)?)/(\d+(?:\.\d+)?) \[")  # tqdm's "done/total ["


def _cli(args: list[str], *, terminal: bool) -> tuple[int, str, str]:
    """Run ``giwbc ARGS`` with stderr on a pseudo-terminal (or a pipe): exit code, stdout, stderr."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    argv = [sys.executable, "-m", "giwbc.apps.cli", *args]
    if not terminal:
        done = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
        return done.returncode, done.stdout, done.stderr
    master, slave = pty.openpty()
    chunks: list[bytes] = []

    def pump() -> None:  # keep reading: a full pseudo-terminal would block the command
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:
                return
            if not data:
                return
            chunks.append(data)

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    try:
        done = subprocess.run(argv, stdout=subprocess.PIPE, stderr=slave, env=env, cwd=ROOT, timeout=300)
    finally:
        os.close(slave)
        reader.join(5)
        os.close(master)
    return done.returncode, done.stdout.decode(), b"".join(chunks).decode(errors="replace")


def test_a_bar_counts_what_it_is_told_and_a_disabled_one_writes_nothing():
    stream = io.StringIO()
    with Progress(4, "episodes", stream=stream) as bar:
        for _ in range(4):
            bar(1)
    assert "episodes: 100%" in stream.getvalue() and "4/4 [" in stream.getvalue()
    silent = io.StringIO()
    with Progress(4, "episodes", enabled=False, stream=silent) as bar:
        bar(4)
    assert silent.getvalue() == "" and not bar.enabled
    assert not wants_progress(stream=io.StringIO())  # not a terminal


def test_walk_shows_progress_on_a_terminal_only():
    code, out, err = _cli(["walk", "--seconds", "0.5", "--json"], terminal=True)
    assert code == 0, err
    assert json.loads(out)["seconds"] == 0.5  # stdout keeps only the result
    done = [(float(a), float(b)) for a, b in BAR.findall(err)]
    assert "walk:" in err and done[0] == (0.0, 0.5) and done[-1] == (0.5, 0.5)
    code, out, err = _cli(["walk", "--seconds", "0.5", "--json"], terminal=False)
    assert code == 0 and json.loads(out)["seconds"] == 0.5
    assert "walk:" not in err and not BAR.search(err)
    code, out, err = _cli(["walk", "--seconds", "0.5", "--json", "--no-progress"], terminal=True)
    assert code == 0 and "walk:" not in err and not BAR.search(err)


def test_sim_to_sim_reports_episodes_from_its_workers_without_pybullets_banner():
    args = ["sim-to-sim", "--conditions", "pybullet", "mujoco_nominal", "--episodes", "2", "--seconds", "0.2", "--workers", "2",
            "--no-policy"]  # fmt: skip
    code, out, err = _cli(args, terminal=True)
    assert code == 0, err
    counts = [(int(a), int(b)) for a, b in BAR.findall(err)]
    assert counts[0] == (0, 4) and counts[-1] == (4, 4)  # 2 episodes x 2 conditions, the WBC alone
    assert "build time" not in out + err
    assert out.startswith("| controller | pybullet | mujoco_nominal |")
    code, out, err = _cli(args + ["--workers", "0"], terminal=False)
    assert code == 0 and "build time" not in out + err and not BAR.search(err)


def _count_to(job: int, tick=None) -> int:
    for _ in range(job):
        if tick is not None:
            tick(1)
    return 10 * job


def test_a_pool_reports_every_unit_and_keeps_the_jobs_order():
    ticks: list[int] = []
    assert map_jobs(_count_to, [3, 1, 2], 2, ticks.append) == [30, 10, 20]
    assert ticks == [1] * 6
    assert map_jobs(_count_to, [3, 1, 2], 0, ticks.append) == [30, 10, 20] and len(ticks) == 12
    assert map_jobs(_count_to, [3, 1, 2], 2) == [30, 10, 20]


def test_banners_are_dropped_and_everything_else_passes(capfd):
    with quiet_banners():
        os.write(2, b"pybullet build time: Jan 29 2025 23:17:20\n")
        os.write(2, b"a real warning\n")
    assert capfd.readouterr().err == "a real warning\n"
