"""The shipped residual policy against the WBC alone under the same seeded pushes.

    python examples/evaluate_residual.py                      # 50 episodes per arm, 80 N, 2 workers
    python examples/evaluate_residual.py --episodes 10 --force 60 80 100

Same as ``giwbc evaluate --policy policies/g1_balance_residual.onnx``. Needs onnxruntime, not torch.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from giwbc.apps.evaluation import add_evaluate_command  # noqa: E402

POLICY = Path(__file__).resolve().parents[1] / "policies" / "g1_balance_residual.onnx"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_evaluate_command(parser.add_subparsers(dest="command"))
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--policy" not in argv:
        argv = ["--policy", str(POLICY), *argv]
    args = parser.parse_args(["evaluate", *argv])
    return args.run(args)


if __name__ == "__main__":
    raise SystemExit(main())
