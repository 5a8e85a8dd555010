"""Baseline timings: MuJoCo physics step and Pinocchio dynamics update for a robot (one JSON object)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import giwbc  # noqa: E402,F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

from giwbc.robot import MujocoRobot, load  # noqa: E402
from giwbc.robot.standing import pd_hold_command  # noqa: E402


def median_us(samples: list[float]) -> float:
    return float(np.median(samples) * 1e6)


def p99_us(samples: list[float]) -> float:
    return float(np.percentile(samples, 99) * 1e6)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--robot", default="g1")
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--feet-only", action="store_true", help="without the whole-body collision shapes (feet boxes only)")
    args = parser.parse_args()

    description = load(args.robot)
    if args.feet_only:
        description = dataclasses.replace(description, collision=())
    robot = MujocoRobot(description)
    robot.set_joint_impedance(pd_hold_command(description))
    model, data = robot.model, robot.data
    robot.step(250)  # settle on the floor so contacts are active
    step_times = []
    for _ in range(args.steps):
        start = time.perf_counter()
        mujoco.mj_step(model, data)
        step_times.append(time.perf_counter() - start)

    pin_model = description.build_pinocchio()
    pin_data = pin_model.createData()
    q, v = robot.generalized_state()
    all_terms, crba_nle = [], []
    for _ in range(args.steps):
        start = time.perf_counter()
        pin.computeAllTerms(pin_model, pin_data, q, v)
        all_terms.append(time.perf_counter() - start)
        start = time.perf_counter()
        pin.crba(pin_model, pin_data, q)
        pin.nonLinearEffects(pin_model, pin_data, q, v)
        crba_nle.append(time.perf_counter() - start)

    print(json.dumps({
        "benchmark": "sim_step",
        "robot": args.robot,
        "collision": "feet only" if args.feet_only else f"whole body ({len(description.collision)} shapes)",
        "samples": args.steps,
        "mujoco_timestep_s": model.opt.timestep,
        "mujoco_step_median_us": round(median_us(step_times), 2),
        "mujoco_step_p99_us": round(p99_us(step_times), 2),
        "mujoco_contacts": int(data.ncon),
        "mujoco_real_time_factor": round(model.opt.timestep / np.median(step_times), 1),
        "pinocchio_compute_all_terms_median_us": round(median_us(all_terms), 2),
        "pinocchio_crba_plus_nle_median_us": round(median_us(crba_nle), 2),
        "ratio_mujoco_step_to_pinocchio_all_terms": round(float(np.median(step_times) / np.median(all_terms)), 2),
    }))


if __name__ == "__main__":
    main()
