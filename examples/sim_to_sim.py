"""Sim-to-sim table: the WBC alone and a residual policy on MuJoCo nominal, MuJoCo randomized and PyBullet.

    python examples/sim_to_sim.py --episodes 50 --seconds 10 --push-force 90 --workers 2 \
        [--policy policies/g1_balance_residual.onnx]

Prints a markdown table of success rates (episodes that did not terminate) and one JSON object.
Without a policy file, only the WBC row is evaluated. See giwbc.apps.sim_to_sim.
"""

from __future__ import annotations

import os
import sys

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

from giwbc.apps.sim_to_sim import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
