"""Figures people read at a glance: push-recovery curves, sim-to-sim bars, estimator error traces.

Each ``*_figure`` function returns a :class:`matplotlib.figure.Figure` built without pyplot (no
global figure registry, no GUI, no GL: the Agg renderer), so tests can check its axes and series;
:func:`save_figure` writes it as .png, .svg or .pdf. matplotlib is an optional dependency imported
inside the functions: :func:`check_plot_path` says so in one line before any long run starts.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from giwbc.errors import ConfigError, UnavailableError

if TYPE_CHECKING:  # the evaluation imports this module for its --plot
    from giwbc.apps.evaluation import ArmResult, Comparison

FORMATS = (".png", ".svg", ".pdf")
SAVED, LOST = "#2a9d3a", "#d1495b"


def _matplotlib() -> Any:
    """The matplotlib module on the Agg renderer, or a one-line error."""
    try:
        import matplotlib  # optional heavy dependency (the `plot` extra)
    except ImportError as error:
        raise UnavailableError("plots need matplotlib: pip install 'giwbc[plot]' (or matplotlib)") from error
    matplotlib.use("Agg", force=False)
    return matplotlib


def new_figure(width: float, height: float) -> Any:
    """A figure with an Agg canvas, outside pyplot's registry."""
    _matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # optional heavy dependency
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def check_plot_path(path: str | os.PathLike[str]) -> Path:
    """Refuse a plot file of an unknown format, or matplotlib missing, before a long run, not after it."""
    path = Path(path)
    if path.suffix.lower() not in FORMATS:
        raise ConfigError(f"plot file {path}: use one of {', '.join(FORMATS)}")
    _matplotlib()
    return path


def save_figure(figure: Any, path: str | os.PathLike[str]) -> Path:
    """Write ``figure`` to ``path`` (format from the suffix)."""
    path = check_plot_path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110, metadata={"Date": None} if path.suffix.lower() in (".svg", ".pdf") else None)
    return path


# --- giwbc evaluate -------------------------------------------------------------------------------
def evaluation_figure(arms: Sequence[ArmResult], comparisons: Sequence[Comparison] = ()) -> Any:
    """Success rate against push impulse (force x duration, N·s) per arm with 95 % Wilson bands; with
    paired comparisons, a second panel of the episodes the residual saves and loses at each impulse."""
    if not arms:
        raise ValueError("nothing to plot: no evaluated arm")
    figure = new_figure(10.5 if comparisons else 6.5, 4.2)
    axes = figure.subplots(1, 2 if comparisons else 1, squeeze=False)[0]
    curve = axes[0]
    names = list(dict.fromkeys(arm.name for arm in arms))
    for name in names:
        rows = sorted((a for a in arms if a.name == name), key=lambda a: a.protocol.force * a.protocol.duration)
        impulse = np.array([a.protocol.force * a.protocol.duration for a in rows])
        rate = np.array([a.success_rate for a in rows])
        band = np.array([a.success_95ci for a in rows])
        label = "WBC alone" if name == "wbc" else f"residual ({name})"
        (line,) = curve.plot(impulse, rate, marker="o", label=label)
        curve.fill_between(impulse, band[:, 0], band[:, 1], color=line.get_color(), alpha=0.2, linewidth=0)
    episodes = sorted({a.n for a in arms})
    curve.set(xlabel="push impulse (N·s)", ylabel="success rate", ylim=(-0.02, 1.02),
              title=f"push recovery, {'/'.join(map(str, episodes))} episodes per point (95 % Wilson)")
    curve.grid(alpha=0.3)
    curve.legend(loc="lower left")
    if comparisons:
        paired = axes[1]
        impulse = np.array([c.wbc.protocol.force * c.wbc.protocol.duration for c in comparisons])
        x = np.arange(len(comparisons))
        saved = [c.saved for c in comparisons]
        lost = [c.lost for c in comparisons]
        bars = [paired.bar(x - 0.2, saved, 0.4, color=SAVED, label="saved by the residual"),
                paired.bar(x + 0.2, lost, 0.4, color=LOST, label="lost by the residual")]
        for group in bars:
            paired.bar_label(group, padding=2)
        paired.set_xticks(x, [f"{i:g}\np={c.paired_p_value:.2g}" for i, c in zip(impulse, comparisons)])
        paired.set(xlabel="push impulse (N·s), exact McNemar p", ylabel="episodes (same seed, same push)",
                   title="paired: what the residual changes")
        paired.set_ylim(0, max(1, *saved, *lost) * 1.45)  # room for the legend above the bars
        paired.legend(loc="upper center", ncol=2, frameon=False)
    return figure


# --- giwbc sim-to-sim ------------------------------------------------------------------------------
def sim_to_sim_figure(cells: Mapping[str, Mapping[str, Any]]) -> Any:
    """The sim-to-sim table as grouped bars: one group per condition, one bar per controller, with
    95 % Wilson intervals and successes / episodes above each bar."""
    controllers = list(cells)
    conditions = list(next(iter(cells.values())))
    figure = new_figure(2.2 + 2.0 * len(conditions), 4.0)
    axes = figure.subplots()
    width = 0.8 / len(controllers)
    x = np.arange(len(conditions))
    for i, controller in enumerate(controllers):
        row = [cells[controller][c] for c in conditions]
        rate = np.array([c.success_rate for c in row])
        band = np.array([c.success_95ci for c in row])
        errors = np.abs(np.vstack([rate - band[:, 0], band[:, 1] - rate]))
        bars = axes.bar(x + (i - (len(controllers) - 1) / 2) * width, rate, width, yerr=errors, capsize=3,
                        label=controller.replace("_", " "))
        axes.bar_label(bars, [f"{c.successes}/{c.episodes}" for c in row], padding=10, fontsize=8)
    axes.set_xticks(x, [c.replace("_", " ") for c in conditions])
    axes.set(ylabel="success rate", ylim=(0, 1.3), yticks=np.linspace(0, 1, 6), xlabel="condition", title="sim-to-sim: same seeds, same pushes (95 % Wilson)")
    axes.grid(axis="y", alpha=0.3)
    axes.legend(loc="upper center", ncol=len(controllers), frameon=False)
    return figure


# --- benchmarks/estimator.py ----------------------------------------------------------------------
ESTIMATOR_TRACES = (("tilt_error_deg", "tilt error (deg)"), ("velocity_error_mps", "velocity error (m/s)"),
                    ("height_error_m", "height error (m)"))  # fmt: skip


def estimator_figure(traces: Mapping[str, Mapping[str, np.ndarray]]) -> Any:
    """Estimator errors against truth over time, one line per run (``{label: {"t": s, key: values}}``
    with the keys of :data:`ESTIMATOR_TRACES`), one panel per error."""
    if not traces:
        raise ValueError("nothing to plot: no estimator run")
    figure = new_figure(9.0, 7.0)
    axes = figure.subplots(len(ESTIMATOR_TRACES), 1, sharex=True)
    for ax, (key, label) in zip(axes, ESTIMATOR_TRACES):
        for name, trace in traces.items():
            ax.plot(trace["t"], trace[key], linewidth=0.8, label=name)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_title("base state estimate against simulator truth")
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time since the estimator was ready (s)")
    return figure
