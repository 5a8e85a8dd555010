"""Base state estimator against MuJoCo truth: G1 standing with pushes, sensor noise on (one JSON object).

Reports the acceptance metrics (orientation error RMS, base linear velocity error RMS, height
drift), the estimator's update time (median / p99, µs) and the noise settings. The default
controller is the joint-PD hold with the pushes it survives (50 N lateral, 20 N sagittal every
2.5 s); ``--controller wbc`` closes the balance controller's loop on the estimate instead.
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

from giwbc.robot import load  # noqa: E402
from giwbc.control.balance import BalanceOnEstimate  # noqa: E402
from giwbc.estimation.evaluation import evaluate, push_sequence  # noqa: E402
from giwbc.robot.standing import PdHold  # noqa: E402
from giwbc.estimation.estimator import EstimatorConfig  # noqa: E402
from giwbc.robot.noise import SensorNoiseConfig  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--robot", default="g1")
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    parser.add_argument("--controller", choices=("pd", "wbc"), default="pd")
    parser.add_argument("--lateral", type=float, default=None, help="lateral push, N (default 50 pd, 60 wbc)")
    parser.add_argument("--sagittal", type=float, default=None, help="sagittal push, N (default 20 pd, 40 wbc)")
    parser.add_argument("--period", type=float, default=2.5, help="seconds between pushes")
    parser.add_argument("--ideal-sensors", action="store_true", help="no noise, bias or latency")
    args = parser.parse_args()

    description = load(args.robot)
    wbc = args.controller == "wbc"
    lateral = args.lateral if args.lateral is not None else (60.0 if wbc else 50.0)
    sagittal = args.sagittal if args.sagittal is not None else (40.0 if wbc else 20.0)
    noise = SensorNoiseConfig.ideal() if args.ideal_sensors else SensorNoiseConfig()
    config = EstimatorConfig()
    controller = BalanceOnEstimate(description) if wbc else PdHold(description)
    pushes = push_sequence(args.duration, period=args.period, lateral=lateral, sagittal=sagittal)
    start = time.perf_counter()
    result = evaluate(
        description, noise=noise, seed=args.seed, duration=args.duration, pushes=pushes, controller=controller, config=config
    )
    wall = time.perf_counter() - start

    print(json.dumps({
        "benchmark": "estimator",
        "robot": args.robot,
        "controller": "balance_wbc_on_estimate" if wbc else "joint_pd_hold",
        "duration_s": args.duration,
        "estimator_rate_hz": round(1.0 / description.timestep),
        "pushes": {
            "count": result.pushes, "lateral_n": lateral, "sagittal_n": sagittal,
            "duration_s": 0.2, "period_s": args.period, "link": "pelvis",
        },
        "orientation_error_rms_deg": round(result.orientation_error_rms_deg, 4),
        "linear_velocity_error_rms_mps": round(result.linear_velocity_error_rms_mps, 4),
        "height_drift_m": round(result.height_drift_m, 5),
        "update_median_us": round(result.update_median_us, 1),
        "update_p99_us": round(result.update_p99_us, 1),
        "tilt_error_rms_deg": round(result.tilt_error_rms_deg, 4),
        "height_error_max_m": round(result.height_error_max_m, 5),
        "horizontal_drift_m": round(result.horizontal_drift_m, 4),
        "angular_velocity_error_rms": round(result.angular_velocity_error_rms, 4),
        "contact_agreement": round(result.contact_agreement, 4),
        "faults": result.fault_counts,
        "stood": result.stood,
        "max_tilt_deg": round(result.max_tilt_deg, 2),
        "noise": {"seed": args.seed, **noise.as_dict()},
        "wall_s": round(wall, 2),
    }))


if __name__ == "__main__":
    main()
