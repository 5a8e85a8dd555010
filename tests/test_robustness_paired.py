"""benchmarks/robustness.py --policy: the paired walker-alone vs policy figures."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from giwbc.apps.evaluation import mcnemar_exact, wilson_interval


def _robustness():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "robustness.py"
    spec = importlib.util.spec_from_file_location("robustness_benchmark", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_paired_counts_discordant_pairs_overall_and_per_plant():
    robustness = _robustness()
    plants = ["point_feet"] * 6 + ["nominal"] * 4
    walker = [False, False, False, False, True, True, True, True, True, False]
    policy = [True, True, True, False, True, True, True, True, False, False]
    row = robustness.paired({"_outcomes": list(zip(walker, plants))}, {"_outcomes": list(zip(policy, plants))})
    paired = row["paired"]
    assert "_outcomes" not in row["walker"] and "_outcomes" not in row["policy"]
    assert (paired["walker_successes"], paired["policy_successes"], paired["saved"], paired["lost"]) == (5, 7, 3, 1)
    assert paired["mcnemar_exact_p"] == mcnemar_exact(3, 1) == pytest.approx(0.625)
    assert paired["policy_95ci"] == [round(v, 3) for v in wilson_interval(7, 10)]
    feet = paired["per_plant"]["point_feet"]
    assert (feet["episodes"], feet["saved"], feet["lost"], feet["walker_successes"]) == (6, 3, 0, 2)
    assert paired["per_plant"]["nominal"]["lost"] == 1
    with pytest.raises(RuntimeError, match="different plants"):
        robustness.paired({"_outcomes": [(True, "nominal")]}, {"_outcomes": [(True, "soft_floor")]})
