"""Choose a G1Walk residual checkpoint on selection seeds (< 1000), never on evaluation seeds.

    python examples/select_walk_checkpoint.py runs/g1_walk_residual --force 80 --episodes 40 --seed 500

The walker alone (zero residual) runs once on the seeds; each checkpoint's ONNX policy runs on the
same seeds and pushes (the walking protocol of ``giwbc evaluate --protocol walk``). Prints one JSON
object per checkpoint (success, saved / lost against the walker alone, exact McNemar p, tracking
RMS difference) and, last, the chosen one: most successes, then fewest lost, then the earliest.

With ``--deploy-check N`` the N best-ranked checkpoints are also deployed, in rank order, over the
emulated CAN path in lockstep (``giwbc deploy --emulate --unpaced --policy ... --vx 0.3 --seconds
20``, the emulated IMU of ``--imu-profile``); the chosen one is then the best-ranked that walks the
20 s without a stop (a fall, a soft joint limit, a controller failure), or none.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from giwbc.apps.evaluation import Comparison, policy_env  # noqa: E402
from giwbc.apps.walk_evaluation import WalkProtocol, cached_arm, paired_tracking  # noqa: E402

EVALUATION_SEEDS = range(1000, 2000)  # kept for fresh-seed evaluation: never used to choose


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a `giwbc train` run folder (its checkpoints/step_*.onnx)")
    parser.add_argument("--force", type=float, default=80.0)
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--seed", type=int, default=500)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--every", type=int, default=1, help="only every n-th checkpoint (the last one always)")
    parser.add_argument("--cache", default="runs/eval_cache", help="arms kept here (the walker-alone arm runs once)")
    parser.add_argument("--deploy-check", type=int, default=0, metavar="N",
                        help="deploy the N best-ranked checkpoints over the emulated CAN path (lockstep) and choose the best that walks")
    parser.add_argument("--deploy-vx", type=float, default=0.3, help="the deploy check's forward command, m/s")
    parser.add_argument("--deploy-seconds", type=float, default=20.0)
    parser.add_argument("--imu-profile", choices=("ahrs", "mems", "cheap"), default="ahrs", help="the deploy check's emulated IMU")
    args = parser.parse_args()
    seeds = range(args.seed, args.seed + args.episodes)
    if seeds.stop > 1000 and seeds.start < 3000:
        parser.error("selection seeds must stay below 1000 (1000-1999 are held out, 2000-2999 confirmation, 3000+ evaluation)")
    checkpoints = sorted((args.run / "checkpoints").glob("step_*.onnx"), key=lambda p: int(re.findall(r"\d+", p.stem)[0]))
    if not checkpoints:
        parser.error(f"no checkpoints in {args.run / 'checkpoints'}")
    checkpoints = [c for i, c in enumerate(checkpoints) if i % args.every == args.every - 1 or c == checkpoints[-1]]
    env_id, env_kwargs = policy_env(checkpoints[0])
    env_kwargs = {k: v for k, v in env_kwargs.items() if k != "max_episode_steps"}
    protocol = WalkProtocol(force=args.force)
    common = {"env_id": env_id, "env_kwargs": env_kwargs, "protocol": protocol, "episodes": args.episodes, "seed": args.seed,
              "workers": args.workers}
    alone = cached_arm(args.cache, None, **common)
    print(json.dumps({"walker_alone": alone.summary()}), flush=True)
    rows = []
    for path in checkpoints:
        comparison = Comparison(alone, cached_arm(args.cache, path, **common), env_id, env_kwargs)
        tracking = paired_tracking(comparison)
        row = {"checkpoint": str(path), "steps": int(re.findall(r"\d+", path.stem)[0]), "success": comparison.residual.success_rate,
               "saved": comparison.saved, "lost": comparison.lost, "mcnemar_p": comparison.paired_p_value,
               "tracking_difference": tracking.mean_difference}
        rows.append(row)
        print(json.dumps(row), flush=True)
    ranked = sorted(rows, key=lambda r: (r["success"], -r["lost"], -r["steps"]), reverse=True)
    best = ranked[0]
    if args.deploy_check:
        best = None
        for row in ranked[: args.deploy_check]:
            check = deploy_check(row["checkpoint"], args.deploy_vx, args.deploy_seconds, args.imu_profile)
            print(json.dumps({"deploy_check": row["checkpoint"], **check}), flush=True)
            if check["walked"]:
                best = row
                break
    print(json.dumps({"chosen": best, "force": args.force, "seeds": [seeds.start, seeds.stop - 1]}))
    return 0


def deploy_check(policy: str, vx: float, seconds: float, imu_profile: str) -> dict[str, object]:
    """The policy deployed over the emulated CAN path in lockstep: walked the whole time without a stop?"""
    command = [sys.executable, "-m", "giwbc.apps.cli", "deploy", "--robot", "g1", "--emulate", "--unpaced", "--policy", policy,
               "--vx", str(vx), "--seconds", str(seconds), "--imu-profile", imu_profile, "--json"]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if not lines:
        return {"walked": False, "exit_code": done.returncode, "message": done.stderr.strip().splitlines()[-1:]}
    report = json.loads(lines[-1])
    standing, walking = report.get("standing") or {}, report.get("walking") or {}
    walked = report["exit_code"] == 0 and bool(standing.get("stood")) and not report["faults"]
    return {"walked": walked, "exit_code": report["exit_code"], "message": report["message"], "steps": walking.get("steps"),
            "dx": standing.get("dx"), "dy": standing.get("dy"), "faults": report["faults"]}


if __name__ == "__main__":
    raise SystemExit(main())
