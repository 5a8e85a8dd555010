"""Plots: each figure's axes and series hold the data they claim (labels, number of series, values),
and the commands write a readable image; a bad plot file is refused before any work."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.apps.cli import main
from giwbc.apps.evaluation import ArmResult, Comparison, EpisodeResult, PushProtocol, wilson_interval
from giwbc.apps.log_report import log_report_figure, pick_joints
from giwbc.apps.plots import estimator_figure, evaluation_figure, save_figure, sim_to_sim_figure
from giwbc.apps.sim_to_sim import Cell
from giwbc.errors import ConfigError
from giwbc.runlog import RunLogWriter, read_log
from giwbc.hal.safety import Fault, FaultKind

matplotlib = pytest.importorskip("matplotlib")


def _arm(name: str, force: float, outcomes: list[bool]) -> ArmResult:
    episodes = tuple(EpisodeResult(seed, ok, ok, 2.6, 0.1, 0.2, 1.3, (force, 0.0, 0.0), 1.0) for seed, ok in enumerate(outcomes))
    return ArmResult(name, PushProtocol(force=force, duration=0.2), episodes)


def test_evaluation_figure_plots_success_against_impulse_with_bands_and_paired_counts(tmp_path):
    wbc = [_arm("wbc", 80, [True] * 8 + [False] * 2), _arm("wbc", 120, [True] * 3 + [False] * 7)]
    residual = [_arm("policy.onnx", 80, [True] * 10), _arm("policy.onnx", 120, [True] * 6 + [False] * 4)]
    comparisons = [Comparison(w, r, "env") for w, r in zip(wbc, residual)]
    figure = evaluation_figure([*wbc, *residual], comparisons)
    curve, paired = figure.axes
    assert curve.get_xlabel() == "push impulse (N·s)" and curve.get_ylabel() == "success rate"
    lines = curve.get_lines()
    assert [line.get_label() for line in lines] == ["WBC alone", "residual (policy.onnx)"]
    np.testing.assert_allclose(lines[0].get_xdata(), [16.0, 24.0])  # 80 N and 120 N for 0.2 s
    np.testing.assert_allclose(lines[0].get_ydata(), [0.8, 0.3])
    np.testing.assert_allclose(lines[1].get_ydata(), [1.0, 0.6])
    bands = curve.collections
    assert len(bands) == 2
    low, high = wilson_interval(3, 10)
    band = bands[0].get_paths()[0].vertices[:, 1]
    assert band.min() == pytest.approx(low) and band.max() == pytest.approx(wilson_interval(8, 10)[1])
    assert high > 0.3 > low
    saved, lost = paired.containers
    assert [b.get_height() for b in saved] == [2, 3] and [b.get_height() for b in lost] == [0, 0]
    assert "episodes" in paired.get_ylabel()
    path = save_figure(figure, tmp_path / "evaluate.png")
    image = matplotlib.image.imread(path)
    assert image.ndim == 3 and image.shape[0] > 300 and image[..., :3].std() > 0.05  # drawn, not blank


def test_evaluation_figure_without_a_policy_has_one_panel():
    figure = evaluation_figure([_arm("wbc", f, [True, False]) for f in (60, 80, 100)])
    assert len(figure.axes) == 1 and len(figure.axes[0].get_lines()) == 1
    np.testing.assert_allclose(figure.axes[0].get_lines()[0].get_ydata(), [0.5, 0.5, 0.5])
    with pytest.raises(ValueError):
        evaluation_figure([])


def test_sim_to_sim_figure_has_one_bar_group_per_condition(tmp_path):
    cells = {
        "wbc_only": {"mujoco_nominal": Cell(10, 9), "mujoco_randomized": Cell(10, 6), "pybullet": Cell(10, 4)},
        "residual_policy": {"mujoco_nominal": Cell(10, 10), "mujoco_randomized": Cell(10, 8), "pybullet": Cell(10, 5)},
    }
    figure = sim_to_sim_figure(cells)
    (axes,) = figure.axes
    bars = [c for c in axes.containers if isinstance(c, matplotlib.container.BarContainer)]
    assert len(bars) == 2
    assert [b.get_height() for b in bars[0]] == pytest.approx([0.9, 0.6, 0.4])
    assert [b.get_height() for b in bars[1]] == pytest.approx([1.0, 0.8, 0.5])
    assert [t.get_text() for t in axes.get_xticklabels()] == ["mujoco nominal", "mujoco randomized", "pybullet"]
    assert axes.get_ylabel() == "success rate"
    assert save_figure(figure, tmp_path / "s2s.svg").read_text().startswith("<?xml")


def test_estimator_figure_has_one_panel_per_error_and_one_line_per_run():
    t = np.linspace(0, 5, 50)
    traces = {name: {"t": t, "tilt_error_deg": k * t, "velocity_error_mps": k * np.ones(50), "height_error_m": -k * t}
              for k, name in enumerate(("ahrs seed 100", "mems seed 100"), start=1)}  # fmt: skip
    figure = estimator_figure(traces)
    assert len(figure.axes) == 3 and all(len(ax.get_lines()) == 2 for ax in figure.axes)
    assert figure.axes[0].get_ylabel() == "tilt error (deg)" and "time" in figure.axes[-1].get_xlabel()
    assert max(figure.axes[0].get_lines()[1].get_ydata()) == pytest.approx(10.0)


@pytest.fixture(scope="module")
def run_log(tmp_path_factory, g1):
    """A run log as a deployment writes it: 0.6 s at 500 Hz, three phases, one fault."""
    path = tmp_path_factory.mktemp("log") / "run.mcap"
    n = len(g1.joint_names)
    with RunLogWriter(path, g1.joint_names, {"robot": "g1", "task": "stand", "controller": "wbc", "control_rate": 500.0}) as log:
        for cycle in range(300):
            t = 0.002 * cycle
            if cycle in (0, 50, 250):
                log.event(cycle, t, "phase", {"phase": {0: "ramp", 50: "running", 250: "damping"}[cycle]})
            q_ref = np.full(n, 0.1)
            q_ref[3] = 0.4 + 0.3 * math.sin(10 * t)  # the left knee moves most
            kind = "damping" if cycle >= 250 else "command"
            log.commands(cycle, t, "running", kind, q_ref, np.zeros(n), np.zeros(n), np.ones(n), np.zeros(n))
            log.replies(cycle, t, q_ref - 0.01, np.zeros(n), np.full(n, 5.0), np.full(n, 30 + 10 * t), np.zeros(n), np.zeros(n, bool), 0, 0, 0)
            log.timing(cycle, t, cycle, 10.0, None if cycle == 0 else 2000.0 + (cycle % 7) * 10, 400.0 + cycle, 50.0, 50.0, cycle == 120)
            log.flush()
        log.fault(Fault(FaultKind.MISSING_REPLIES, "motor silent", 200, 0.4, (g1.joint_names[3],)))
    return path


def test_log_report_shows_tracking_limits_temperatures_timing_phases_and_faults(run_log, g1):
    log = read_log(run_log)
    assert g1.joint_names[3] in pick_joints(log) and len(pick_joints(log)) == 3
    chosen = [g1.joint_names[3], g1.joint_names[0]]
    figure = log_report_figure(log, chosen)
    axes = {ax.get_ylabel(): ax for ax in figure.axes}
    tracking = axes["joint position (rad)"]
    labels = [line.get_label() for line in tracking.get_lines() if line.get_label() != "_fault"]
    assert labels == [f"{chosen[0]} reference", f"{chosen[0]} measured", f"{chosen[1]} reference", f"{chosen[1]} measured"]
    reference = tracking.get_lines()[0].get_ydata()
    assert np.nanmax(reference) == pytest.approx(0.7, abs=1e-3) and np.isnan(reference[250:]).all()  # damping: no reference
    torque = axes["torque (N·m)"]
    limit = dict(zip(g1.joint_names, g1.effort_limits))[chosen[0]]
    levels = {round(float(line.get_ydata()[0]), 3) for line in torque.get_lines() if line.get_linestyle() == ":"}
    assert {round(limit, 3), round(-limit, 3)} <= levels
    temperature = axes["temperature (°C)"]
    hottest = [line for line in temperature.get_lines() if line.get_label() == "hottest motor"]
    assert len(hottest) == 1 and hottest[0].get_ydata().max() == pytest.approx(30 + 10 * 0.598, abs=0.01)
    phases = axes["phase"]
    assert [t.get_text().strip() for t in phases.texts] == ["ramp", "running", "damping", "missing_replies"]
    for ax in (tracking, torque, temperature, phases):  # the fault across every time panel
        assert [line.get_xdata()[0] for line in ax.get_lines() if line.get_label() == "_fault"] == [pytest.approx(0.4)]
    histograms = axes["cycles"]  # the work-time histogram (the last axes with that label)
    assert "1 overruns" in histograms.get_title()
    period = [ax for ax in figure.axes if ax.get_xlabel().startswith("period")][0]
    assert sum(p.get_height() for p in period.patches) == 299  # every measured period (the first has none)
    assert min(p.get_x() for p in period.patches) == pytest.approx(0.0) and period.get_xlim()[1] >= 60.0  # 2000..2060 us


def test_log_plot_command_writes_the_report_and_refuses_bad_input(run_log, tmp_path, capsys):
    out = tmp_path / "report.png"
    assert main(["log", "plot", str(run_log), "-o", str(out)]) == 0
    image = matplotlib.image.imread(out)
    assert image.shape[0] > 1000 and image[..., :3].std() > 0.05
    assert main(["log", "plot", str(run_log), "-o", str(tmp_path / "report.txt")]) == 2
    with pytest.raises(SystemExit) as refused:  # refused while parsing
        main(["log", "plot", str(tmp_path / "missing.mcap")])
    assert refused.value.code == 2
    assert main(["log", "plot", str(run_log), "--joints", "elbow_of_nobody", "-o", str(out)]) == 2
    assert "elbow_of_nobody" in capsys.readouterr().err


def test_evaluate_refuses_a_plot_file_it_cannot_write_before_running(capsys):
    assert main(["evaluate", "--episodes", "1000", "--plot", "curve.txt"]) == 2
    assert "curve.txt" in capsys.readouterr().err
