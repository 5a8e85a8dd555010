"""The shipped G1Balance residual policy: its metadata matches the robot and it deploys as trained."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("onnxruntime")

from giwbc.apps.deploy import DeployOptions, deploy  # noqa: E402
from giwbc.policy import OnnxPolicy  # noqa: E402
from giwbc.runtimes.phases import StartupConfig  # noqa: E402

SHIPPED = Path(__file__).resolve().parents[1] / "policies" / "g1_balance_residual.onnx"


def test_shipped_policy_metadata(g1) -> None:
    metadata = OnnxPolicy(SHIPPED).metadata
    assert metadata["joint_names"] == list(g1.joint_names)
    assert metadata["action_names"] == ["com/x", "com/y", "com/z", "orientation/roll", "orientation/pitch", "orientation/yaw"]
    assert metadata["env_kwargs"]["residuals"] == ["com", "orientation"]
    assert metadata["rates"]["controller_hz"] == 500.0 and metadata["training"]["timesteps"] == 409_600


def test_shipped_policy_deploys_over_the_emulated_can_buses(g1, tmp_path) -> None:
    """Its training-only options (pushes, time limit) are dropped; the WBC and the policy run, the robot stands."""
    options = DeployOptions(
        policy=str(SHIPPED), emulate=True, realtime=False, seconds=1.0, log=str(tmp_path / "run.mcap"),
        startup=StartupConfig(settle_time=0.02, ramp_time=0.3, shutdown_time=0.1, off_delay=0.05),
    )  # fmt: skip
    outcome = deploy(options, description=g1, out=None)
    assert outcome.exit_code == 0, outcome.message
    assert outcome.standing is not None and outcome.standing["stood"]


def test_the_demo_finds_the_shipped_policy() -> None:
    """`make demo` runs the residual policy from the repository's policies/ folder."""
    from giwbc.apps.evaluation import SHIPPED_POLICY

    assert Path(SHIPPED_POLICY) == SHIPPED and SHIPPED.is_file()
