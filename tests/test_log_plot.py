"""``giwbc log plot`` on the logs a default ``giwbc deploy`` writes (scene channels included: ``/robot_description``,
``/tf``, ``/joint_states``, ... carry no robot time ``t``): a standing, a walking and a policy deploy each plot, and
the report holds every panel with the run's data (tracking, torques, temperatures, every phase, both histograms)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from giwbc.apps.cli import main
from giwbc.apps.log_report import log_report_figure
from giwbc.runlog import read_log

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")

ROOT = Path(__file__).resolve().parents[1]
DEPLOYS = {
    "stand": [],
    "walk": ["--controller", "walk", "--vx", "0.2"],
    "policy": ["--policy", str(ROOT / "policies" / "g1_walk_residual.onnx")],
}
PHASES = ["enable", "settle", "ramp", "calibrate", "running", "shutdown", "damping", "off"]


@pytest.fixture(scope="module", params=sorted(DEPLOYS))
def deploy_log(request, tmp_path_factory) -> tuple[str, Path]:
    """The default log (scene channels on) of a short, unpaced, emulated deploy."""
    path = tmp_path_factory.mktemp(request.param) / f"{request.param}.mcap"
    command = [sys.executable, "-m", "giwbc.apps.cli", "deploy", "--robot", "g1", "--emulate", "--seconds", "0.5", "--unpaced",
               "--log", str(path), *DEPLOYS[request.param]]
    done = subprocess.run(command, capture_output=True, text=True, timeout=180, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    return request.param, path


@pytest.mark.slow
def test_log_plot_draws_every_panel_of_a_default_deploy_log(deploy_log, tmp_path):
    kind, path = deploy_log
    log = read_log(path)
    assert {"/robot_description", "/tf", "/joint_states"} <= set(log.messages)  # the channels that had no `t`
    out = tmp_path / "report.png"
    assert main(["log", "plot", str(path), "-o", str(out)]) == 0
    image = matplotlib.image.imread(out)
    assert image.shape[0] > 1000 and image[..., :3].std() > 0.05

    figure = log_report_figure(log)
    axes = {ax.get_ylabel(): ax for ax in figure.axes}
    assert {"joint position (rad)", "torque (N·m)", "temperature (°C)", "phase", "cycles"} <= set(axes)
    tracking = axes["joint position (rad)"]
    labels = [line.get_label() for line in tracking.get_lines()]
    assert sum(label.endswith(" reference") for label in labels) == 3 and sum(label.endswith(" measured") for label in labels) == 3
    cycles = len(log.topic("/replies"))
    measured = [line for line in tracking.get_lines() if line.get_label().endswith(" measured")][0]
    assert len(measured.get_ydata()) == cycles and np.isfinite(measured.get_ydata()).all()
    assert np.ptp(measured.get_xdata()) > 0.5  # robot time, not the scene's wall clock
    temperature = axes["temperature (°C)"]
    assert any(line.get_label() == "hottest motor" for line in temperature.get_lines())
    assert [text.get_text().strip() for text in axes["phase"].texts] == PHASES  # a clean run: no fault marks
    period = [ax for ax in figure.axes if ax.get_xlabel().startswith("period")][0]
    finite = np.isfinite(log.array("/timing", "period_us")).sum()
    assert sum(p.get_height() for p in period.patches) == finite > 0
    work = [ax for ax in figure.axes if ax.get_xlabel() == "work time (µs)"][0]
    assert "overruns" in work.get_title()
    if kind == "walk":
        assert log.metadata["controller"] == "walk"
    if kind == "policy":
        assert str(log.metadata["policy"]).endswith("g1_walk_residual.onnx")
