"""``giwbc walk``: a short walk prints a JSON summary with the figures the issue asks for; a
non-finite command is refused, one beyond the gait limits clamped with a note."""

from __future__ import annotations

import json

import pytest

from giwbc.apps.cli import main

pytestmark = pytest.mark.slow


def test_walk_prints_a_summary_and_moves_forward(capsys):
    code = main(["walk", "--robot", "g1", "--vx", "0.3", "--seconds", "3.5", "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and not result["fell"]
    assert result["steps"] >= 5 and result["distance"][0] > 0.4
    assert result["mean_velocity"][0] == pytest.approx(0.3, abs=0.1)
    assert result["wbc_tick_single_support_median_us"] > 0


def test_walk_clamps_a_command_beyond_the_limits_and_refuses_nan(capsys):
    code = main(["walk", "--vx", "5", "--seconds", "1.0", "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and any("vx = 5" in note and "clamped" in note for note in result["notes"])
    with pytest.raises(SystemExit, match="finite"):
        main(["walk", "--vx", "nan", "--seconds", "1.0"])
