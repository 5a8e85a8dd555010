"""Base state estimator against MuJoCo truth, per IMU profile, and the WBC's tolerance (one JSON object).

For each IMU profile (``ahrs``, ``mems``, ``cheap``: :data:`giwbc.robot.noise.IMU_PROFILES`) and
each seed, the G1 stands under the balance WBC closed on the estimate (``--controller pd``: the
joint-PD hold) through the usual pushes (60 N lateral, 40 N sagittal every 2.5 s; 50/20 N for
the PD hold), after the estimator's start-up standstill calibration. Reported per profile: the
acceptance metrics (tilt and orientation error RMS, base velocity error RMS, height drift,
heading drift per minute), how many seeds stood, the calibration time, the estimator's update
time (median / p99, us), and per seed the same.

``--grid``: the WBC's tolerance, mapped: the ``mems`` profile with its gyro turn-on bias, its
accelerometer turn-on bias and its IMU latency set per cell (``--grid-gyro``, ``--grid-accel``,
``--grid-latency``; the default is a modest 2 x 2 x 2 grid, ``--full-grid`` a 4 x 4 x 3 one),
``--grid-seeds`` seeds per cell, reporting which cells stood on every seed.

``--plot FILE`` (.png, .svg): the tilt, velocity and height errors against time of every profile and
seed. A progress bar (runs done) is drawn on stderr when it is a terminal (``--no-progress``: never).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import giwbc  # noqa: E402,F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
import numpy as np  # noqa: E402

from giwbc.apps.plots import check_plot_path, estimator_figure, save_figure  # noqa: E402
from giwbc.apps.progress import Progress, add_progress_argument, wants_progress  # noqa: E402
from giwbc.robot import load  # noqa: E402
from giwbc.control.balance import BalanceOnEstimate  # noqa: E402
from giwbc.estimation.evaluation import evaluate, push_sequence  # noqa: E402
from giwbc.estimation.estimator import EstimatorConfig  # noqa: E402
from giwbc.robot.noise import IMU_PROFILES, SensorNoiseConfig  # noqa: E402
from giwbc.robot.standing import PdHold  # noqa: E402

METRICS = (
    "tilt_error_rms_deg", "orientation_error_rms_deg", "linear_velocity_error_rms_mps", "height_drift_m",
    "heading_drift_deg_per_min", "ready_time_s", "max_tilt_deg", "update_median_us", "update_p99_us",
)  # fmt: skip
DEG = math.pi / 180.0
FULL_GRID = {"gyro": [0.5, 1.0, 2.0, 4.0], "accel": [20.0, 60.0, 120.0, 250.0], "latency": [1, 2, 4]}


def _run(description, model, noise: SensorNoiseConfig, seed: int, args, lateral: float, sagittal: float,
         traces: dict | None = None, label: str = "") -> dict:
    wbc = args.controller == "wbc"
    controller = BalanceOnEstimate(description) if wbc else PdHold(description)
    pushes = push_sequence(args.duration, period=args.period, lateral=lateral, sagittal=sagittal)
    result = evaluate(description, noise=noise, seed=seed, duration=args.duration, pushes=pushes, controller=controller,
                      config=EstimatorConfig.for_sensors(noise), mujoco_model=model, traces=traces is not None)
    if traces is not None:
        traces[label] = result.traces
    row = {key: round(getattr(result, key), 5) for key in METRICS}
    row.update(seed=seed, stood=result.stood, faults=result.fault_counts)
    return row


def _summary(rows: list[dict]) -> dict:
    out: dict[str, object] = {"seeds": len(rows), "stood": sum(r["stood"] for r in rows)}
    for key in METRICS:
        values = np.array([r[key] for r in rows], float)
        out[key] = {"mean": round(float(np.nanmean(values)), 5), "max": round(float(np.nanmax(values)), 5)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robot", default="g1")
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds after calibration")
    parser.add_argument("--seeds", default="100-109", help="sensor-noise seeds: 'a-b' or 'a,b,c' (tune on 0-9, report on fresh ones)")
    parser.add_argument("--profiles", default="ahrs,mems,cheap", help=f"IMU profiles, of {sorted(IMU_PROFILES)}")
    parser.add_argument("--controller", choices=("pd", "wbc"), default="wbc")
    parser.add_argument("--lateral", type=float, default=None, help="lateral push, N (default 60 wbc, 50 pd)")
    parser.add_argument("--sagittal", type=float, default=None, help="sagittal push, N (default 40 wbc, 20 pd)")
    parser.add_argument("--period", type=float, default=2.5, help="seconds between pushes")
    parser.add_argument("--grid", action="store_true", help="also map the WBC's tolerance (gyro bias x accel bias x latency)")
    parser.add_argument("--full-grid", action="store_true", help="the full 4 x 4 x 3 tolerance grid (implies --grid)")
    parser.add_argument("--grid-gyro", default="0.5,4", help="gyro turn-on bias std, deg/s")
    parser.add_argument("--grid-accel", default="20,250", help="accelerometer turn-on bias std, mg")
    parser.add_argument("--grid-latency", default="2,4", help="IMU latency, samples")
    parser.add_argument("--grid-seeds", default="100,101", help="seeds per grid cell")
    parser.add_argument("--grid-duration", type=float, default=10.0, help="simulated seconds per grid cell")
    parser.add_argument("--plot", default=None, metavar="FILE", help="error traces against time (.png, .svg, .pdf)")
    add_progress_argument(parser)
    args = parser.parse_args()
    if args.plot:
        check_plot_path(args.plot)

    description = load(args.robot)
    model = description.build_mujoco()
    wbc = args.controller == "wbc"
    lateral = args.lateral if args.lateral is not None else (60.0 if wbc else 50.0)
    sagittal = args.sagittal if args.sagittal is not None else (40.0 if wbc else 20.0)
    seeds = _seeds(args.seeds)
    start = time.perf_counter()
    report: dict[str, object] = {
        "benchmark": "estimator", "robot": args.robot,
        "controller": "balance_wbc_on_estimate" if wbc else "joint_pd_hold",
        "duration_s": args.duration, "estimator_rate_hz": round(1.0 / description.timestep), "seeds": seeds,
        "pushes": {"lateral_n": lateral, "sagittal_n": sagittal, "duration_s": 0.2, "period_s": args.period, "link": "pelvis"},
        "profiles": {},
    }  # fmt: skip
    profiles = args.profiles.split(",")
    traces: dict | None = {} if args.plot else None
    bar = Progress(len(profiles) * len(seeds), "estimator", unit="run", enabled=wants_progress(args))
    for name in profiles:
        noise = SensorNoiseConfig.profile(name)
        rows = []
        for seed in seeds:
            rows.append(_run(description, model, noise, seed, args, lateral, sagittal, traces, f"{name} seed {seed}"))
            bar(1)
        report["profiles"][name] = {"summary": _summary(rows), "sensors": noise.as_dict(), "runs": rows}  # type: ignore[index]
    bar.close()
    if traces is not None:
        report["plot"] = str(save_figure(estimator_figure(traces), args.plot))
    if args.grid or args.full_grid:
        gyro = FULL_GRID["gyro"] if args.full_grid else _floats(args.grid_gyro)
        accel = FULL_GRID["accel"] if args.full_grid else _floats(args.grid_accel)
        latency = FULL_GRID["latency"] if args.full_grid else [int(x) for x in _floats(args.grid_latency)]
        grid_seeds = _seeds(args.grid_seeds)
        grid_args = argparse.Namespace(**{**vars(args), "duration": args.grid_duration})
        cells = []
        for g, a, lat in itertools.product(gyro, accel, latency):
            noise = SensorNoiseConfig.profile("mems", gyro_bias=g * DEG, accel_bias=a * 1e-3 * 9.80665, imu_latency=int(lat))
            rows = [_run(description, model, noise, seed, grid_args, lateral, sagittal) for seed in grid_seeds]
            cells.append({
                "gyro_bias_deg_s": g, "accel_bias_mg": a, "imu_latency": int(lat), "stood": sum(r["stood"] for r in rows),
                "seeds": len(rows), "tilt_error_rms_deg": round(max(r["tilt_error_rms_deg"] for r in rows), 4),
            })  # fmt: skip
        report["tolerance_grid"] = {"profile": "mems", "duration_s": args.grid_duration, "seeds": grid_seeds, "cells": cells}
    report["wall_s"] = round(time.perf_counter() - start, 1)
    print(json.dumps(report))


def _seeds(text: str) -> list[int]:
    if "-" in text:
        first, last = (int(x) for x in text.split("-"))
        return list(range(first, last + 1))
    return [int(x) for x in text.split(",")]


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",")]


if __name__ == "__main__":
    main()
