"""Choose a G1Walk residual checkpoint on selection seeds (< 1000), never on evaluation seeds.

    python examples/select_walk_checkpoint.py runs/g1_walk_residual --force 80 --episodes 40 --seed 500

The walker alone (zero residual) runs once on the seeds; each checkpoint's ONNX policy runs on the
same seeds and pushes (the walking protocol of ``giwbc evaluate --protocol walk``). Prints one JSON
object per checkpoint (success, saved / lost against the walker alone, exact McNemar p, tracking
RMS difference) and, last, the chosen one: most successes, then fewest lost, then the earliest.
"""

from __future__ import annotations

import argparse
import json
import os
import re
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
    best = max(rows, key=lambda r: (r["success"], -r["lost"], -r["steps"]))
    print(json.dumps({"chosen": best, "force": args.force, "seeds": [seeds.start, seeds.stop - 1]}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
