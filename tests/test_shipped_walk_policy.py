"""The shipped G1Walk residual policy: its metadata matches the robot and the task, and it walks in `giwbc play`."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("onnxruntime")

from giwbc.apps.cli import main  # noqa: E402
from giwbc.policy import OnnxPolicy  # noqa: E402

SHIPPED = Path(__file__).resolve().parents[1] / "policies" / "g1_walk_residual.onnx"


def test_shipped_walk_policy_metadata(g1) -> None:
    metadata = OnnxPolicy(SHIPPED).metadata
    assert metadata["env_id"] == "giwbc/G1Walk-v0" and metadata["joint_names"] == list(g1.joint_names)
    assert metadata["action_names"] == ["step/x", "step/y", "step/duration", "orientation/roll", "orientation/pitch", "orientation/yaw",
                                        "hip/roll_gain"]
    assert metadata["env_kwargs"]["residuals"] == ["step", "orientation", "hip"]
    assert metadata["rates"]["controller_hz"] == 500.0 and metadata["rates"]["agent_hz"] == 50.0
    assert metadata["training"]["seed"] == 0 and metadata["training"]["timesteps"] > 0


def test_shipped_walk_policy_walks_in_play(capsys) -> None:
    """Two seconds of walking on the training commands and pushes without a fall (1.5 s before the first push can start)."""
    assert main(["play", "--policy", str(SHIPPED), "--max-steps", "75", "--seed", "5", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["lengths"] == [75] and summary["returns"][0] > 75 * 1.5  # alive + tracking + upright, no fall penalty
