"""``giwbc log plot RUN.mcap -o report.png``: a deploy run on one page.

Time panels share one axis (robot time since the run started): joint tracking (reference against
measured) for a few joints, their measured torques against the description's limits, the motor
temperatures, and the run's phases with its faults (red lines across every time panel). Below, the
histograms of the period error (measured period minus the nominal one) and of the loop's work time
per cycle, with the overruns counted. Reads only the run log (:func:`giwbc.runlog.read_log`).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from collections.abc import Sequence
from typing import Any

import numpy as np

from giwbc.apps.arguments import add_command, existing_file
from giwbc.apps.plots import check_plot_path, new_figure, save_figure
from giwbc.errors import ConfigError, RobotDescriptionError
from giwbc.runlog import RunLog, read_log
from giwbc.robot import load

DEFAULT_JOINTS = 3  # joints shown when none are named: those whose reference moved most
FAULT_COLOR = "#d1495b"


def pick_joints(log: RunLog, joints: Sequence[str] | None = None, count: int = DEFAULT_JOINTS) -> list[str]:
    """The named joints (checked against the log), or the ``count`` whose reference moved most."""
    names = list(log.joint_names)
    if joints:
        unknown = [j for j in joints if j not in names]
        if unknown:
            raise ConfigError(f"joints {unknown} are not in the log (its joints: {', '.join(names)})")
        return list(joints)
    q_ref = references(log)
    if q_ref.size == 0:
        return names[:count]
    spread = np.nan_to_num(np.nanmax(q_ref, axis=0) - np.nanmin(q_ref, axis=0), nan=-1.0)
    return [names[i] for i in sorted(np.argsort(-spread, kind="stable")[:count])]


def references(log: RunLog) -> np.ndarray:
    """The position references sent, per cycle (NaN where the frame was not a position command:
    enable, damping, off frames carry no reference)."""
    q_ref = log.array("/commands", "q_ref")
    if q_ref.size:
        commanded = np.array([m.get("kind") == "command" for m in log.topic("/commands")])
        q_ref[~commanded] = np.nan
    return q_ref


def effort_limits(log: RunLog) -> dict[str, float]:
    """Joint effort limits of the robot the log names (empty if it is not a shipped robot)."""
    try:
        description = load(str(log.metadata.get("robot", "")))
    except (RobotDescriptionError, FileNotFoundError, KeyError, ValueError):
        return {}
    return {name: float(limit) for name, limit in zip(description.joint_names, description.effort_limits) if limit > 0}


def phases(log: RunLog) -> list[tuple[str, float, float]]:
    """``(phase, start, end)`` from the phase events, the last ending with the log's last timed message
    (the scene channels -- ``/robot_description``, ``/tf``, ``/joint_states``, ... -- carry no robot time ``t``)."""
    marks = [(e["detail"]["phase"], float(e["t"])) for e in log.events if e["event"] == "phase"]
    end = max((float(m["t"]) for topic in log.messages.values() for m in topic[-1:] if "t" in m), default=0.0)
    return [(name, start, marks[i + 1][1] if i + 1 < len(marks) else end) for i, (name, start) in enumerate(marks)]


def log_report_figure(log: RunLog, joints: Sequence[str] | None = None, limits: dict[str, float] | None = None) -> Any:
    """The one-page report of a run log (see the module docstring)."""
    chosen = pick_joints(log, joints)
    index = [log.joint_names.index(j) for j in chosen]
    limits = effort_limits(log) if limits is None else limits
    figure = new_figure(11.0, 12.0)
    mosaic = [["tracking", "tracking"], ["torque", "torque"], ["temperature", "temperature"], ["phases", "phases"], ["period", "work"]]
    axes = figure.subplot_mosaic(mosaic, height_ratios=[3.0, 2.5, 1.8, 0.8, 2.4])
    timeline = [axes[k] for k in ("tracking", "torque", "temperature", "phases")]
    for ax in timeline[1:]:
        ax.sharex(timeline[0])
    run = log.metadata.get("robot", "robot")
    figure.suptitle(f"{log.path.name}: {run}, {log.metadata.get('task', '?')} ({log.metadata.get('controller', '?')}) "
                    f"at {log.metadata.get('control_rate', '?')} Hz")

    t_cmd, t_rep = log.array("/commands", "t"), log.array("/replies", "t")
    q_ref, q = references(log), log.array("/replies", "q")
    tau = log.array("/replies", "tau")
    colors = [f"C{i}" for i in range(len(chosen))]
    ax = axes["tracking"]
    for color, name, i in zip(colors, chosen, index):
        if q_ref.size:
            ax.plot(t_cmd, q_ref[:, i], color=color, linestyle="--", linewidth=1.0, label=f"{name} reference")
        if q.size:
            ax.plot(t_rep, q[:, i], color=color, linewidth=1.0, label=f"{name} measured")
    ax.set(ylabel="joint position (rad)", title="joint tracking: reference (dashed) vs measured")
    ax.legend(fontsize=7, ncol=2, loc="best")

    ax = axes["torque"]
    for color, name, i in zip(colors, chosen, index):
        if tau.size:
            ax.plot(t_rep, tau[:, i], color=color, linewidth=1.0, label=name)
        if name in limits:
            for sign in (1.0, -1.0):
                ax.axhline(sign * limits[name], color=color, linestyle=":", linewidth=1.0)
    ax.set(ylabel="torque (N·m)", title="measured torque; dotted: the joint's effort limit")
    ax.legend(fontsize=7, loc="best")

    ax = axes["temperature"]
    temperature = log.array("/replies", "temperature")
    if temperature.size:
        for color, name, i in zip(colors, chosen, index):
            ax.plot(t_rep, temperature[:, i], color=color, linewidth=1.0, label=name)
        ax.plot(t_rep, np.nanmax(temperature, axis=1), color="k", linewidth=1.2, label="hottest motor")
    ax.set(ylabel="temperature (°C)")
    ax.legend(fontsize=7, loc="best")

    ax = axes["phases"]
    spans = phases(log)
    for k, (name, start, end) in enumerate(spans):
        ax.broken_barh([(start, max(end - start, 1e-6))], (0, 1), color=f"C{k % 10}", alpha=0.35)
        ax.text(start, 0.5, f" {name}", va="center", fontsize=7, clip_on=True)
    for fault in log.faults:
        for axis in timeline:
            axis.axvline(float(fault["t"]), color=FAULT_COLOR, linewidth=1.2, label="_fault")  # "_": not in legends
        ax.text(float(fault["t"]), 1.05, fault["kind"], color=FAULT_COLOR, fontsize=7, rotation=20)
    ax.set(yticks=[], ylim=(0, 1), xlabel="robot time (s)", ylabel="phase")
    for axis in timeline[:-1]:
        axis.tick_params(labelbottom=False)
        axis.grid(alpha=0.3)

    period = log.array("/timing", "period_us")
    work = log.array("/timing", "work_us")
    overruns = int(sum(bool(m.get("overrun")) for m in log.topic("/timing")))
    rate = float(log.metadata.get("control_rate") or 0.0)
    nominal = 1e6 / rate if rate > 0 else float(np.nanmedian(period)) if np.isfinite(period).any() else 0.0
    error = period[np.isfinite(period)] - nominal
    ax = axes["period"]
    if error.size:
        ax.hist(error, bins=60, color="C0")
        p99 = float(np.percentile(np.abs(error), 99))
        ax.set_title(f"period error: |p99| {p99:.0f} µs over {error.size} periods", fontsize=9)
    ax.set(xlabel=f"period − {nominal:.0f} µs (µs)", ylabel="cycles")
    ax.set_yscale("log")
    ax = axes["work"]
    if work.size:
        ax.hist(work[np.isfinite(work)], bins=60, color="C1")
        ax.axvline(nominal, color=FAULT_COLOR, linestyle="--", linewidth=1.0, label="period")
        ax.legend(fontsize=7)
        ax.set_title(f"work per cycle: median {np.nanmedian(work):.0f} µs, {overruns} overruns", fontsize=9)
    ax.set(xlabel="work time (µs)", ylabel="cycles")
    ax.set_yscale("log")
    return figure


# --- command line ------------------------------------------------------------------------------
def add_log_command(commands: Any) -> None:
    """Add ``giwbc log plot`` to an argparse subparsers object."""
    parser = add_command(commands, "log", "look at a deploy run log (.mcap)")
    actions = parser.add_subparsers(dest="log_command", required=True, metavar="ACTION")
    plot = add_command(actions, "plot", "a one-page report of a run: tracking, torques, temperatures, timing, phases, faults")
    plot.add_argument("log", type=existing_file(".mcap"), help="run log (.mcap) written by `giwbc deploy`")
    plot.add_argument("-o", "--output", default=None, help="image file (.png, .svg, .pdf); default: the log's name with .png")
    plot.add_argument("--joints", nargs="+", default=None, help=f"joints to show (default: the {DEFAULT_JOINTS} that moved most)")
    plot.set_defaults(run=run_log_plot_command)


def run_log_plot_command(args: argparse.Namespace) -> int:
    source = Path(args.log)
    if not source.is_file():
        raise ConfigError(f"no run log at {source}")
    output = check_plot_path(args.output or source.with_suffix(".png"))
    log = read_log(source)
    if not log.messages or not log.joint_names:
        raise ConfigError(f"{source} is not a run log written by `giwbc deploy` (no messages or no joint names)")
    written = save_figure(log_report_figure(log, args.joints), output)
    print(f"report: {written}")
    return 0
