"""The command line: robots listing, headless simulation, clear errors."""

from __future__ import annotations

import json

import pytest

from giwbc.apps.cli import main


def test_robots_lists_dofs_and_mass(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["robots"]) == 0
    out = capsys.readouterr().out
    g1_line = next(line for line in out.splitlines() if line.startswith("g1"))
    assert g1_line.split()[1:4] == ["29", "29", "33.34"]
    assert any(line.startswith("cartpole") for line in out.splitlines())


def test_sim_g1_stands_and_reports_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "--robot", "g1", "--seconds", "2", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["stood"] and summary["seconds"] == pytest.approx(2.0)
    assert summary["vertical_contact_force"] == pytest.approx(summary["weight"], rel=0.01)


def test_sim_unknown_robot_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "--robot", "nao"]) == 2
    assert "unknown robot 'nao'" in capsys.readouterr().err
