"""The shipped robots and policies are found by name wherever giwbc runs (a checkout here; the
wheel's copy when installed: tests/test_wheel_install.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from giwbc.apps.arguments import policy_file
from giwbc.util.shipped import shipped_folder, shipped_policies, shipped_policy

ROOT = Path(__file__).resolve().parents[1]


def test_a_checkout_ships_its_top_level_folders() -> None:
    assert shipped_folder("robots") == ROOT / "robots" and shipped_folder("policies") == ROOT / "policies"
    assert set(shipped_policies()) == {p.stem for p in (ROOT / "policies").glob("*.onnx")} >= {"g1_balance_residual", "g1_walk_residual"}
    assert shipped_policy("g1_walk_residual") == shipped_policy("g1_walk_residual.onnx") == ROOT / "policies" / "g1_walk_residual.onnx"
    assert shipped_policy("g1_nope") is None
    with pytest.raises(ValueError, match="unknown kind of shipped data 'videos'"):
        shipped_folder("videos")


def test_a_policy_option_takes_a_file_or_a_shipped_name(tmp_path: Path, monkeypatch) -> None:
    parse = policy_file()
    shipped = str(ROOT / "policies" / "g1_balance_residual.onnx")
    own = tmp_path / "mine.onnx"
    own.write_bytes(b"weights")
    monkeypatch.chdir(tmp_path)  # away from the checkout: policies/ does not exist here
    assert parse("g1_balance_residual") == parse("g1_balance_residual.onnx") == shipped
    assert parse("policies/g1_balance_residual.onnx") == shipped  # the docs' path, from anywhere
    assert parse("mine.onnx") == "mine.onnx" and parse(str(own)) == str(own)  # a file is taken as given
    (tmp_path / "g1_walk_residual.onnx").write_bytes(b"local")
    assert parse("g1_walk_residual.onnx") == "g1_walk_residual.onnx"  # a file here wins over the shipped name
    for wrong, reason in [("g1_nope", "expected a .onnx file"), ("elsewhere/g1_balance_residual.onnx", "no such file"),
                          ("empty.onnx", "empty file")]:
        (tmp_path / "empty.onnx").write_bytes(b"")
        with pytest.raises(argparse.ArgumentTypeError, match=rf"{reason}, and not a shipped policy \(shipped: g1_balance_residual, g1_walk_residual\)$"):
            parse(wrong)


def test_deploy_loads_a_shipped_policy_by_name(tmp_path: Path, monkeypatch) -> None:
    from giwbc.apps.deploy_setup import load_policy
    from giwbc.errors import DeployError
    from giwbc.util.shipped import policy_by_name

    monkeypatch.chdir(tmp_path)
    assert policy_by_name("policies/g1_walk_residual.onnx") == ROOT / "policies" / "g1_walk_residual.onnx"
    assert policy_by_name("elsewhere/g1_walk_residual.onnx") is None and policy_by_name("g1_nope") is None
    _, metadata = load_policy("g1_walk_residual")
    assert metadata["env_id"] == "giwbc/G1Walk-v0"
    with pytest.raises(DeployError, match="no policy file at g1_nope.onnx"):
        load_policy("g1_nope.onnx")
