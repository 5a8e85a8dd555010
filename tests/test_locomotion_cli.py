"""``giwbc walk``: a short walk prints a JSON summary with the figures the issue asks for; a
non-finite command is refused, one beyond the gait limits clamped with a note."""

from __future__ import annotations

import json

import pytest

from giwbc.apps.cli import main
from giwbc.apps.walk import followed_command

pytestmark = pytest.mark.slow


def test_walk_prints_a_summary_and_moves_forward(capsys):
    code = main(["walk", "--robot", "g1", "--vx", "0.3", "--seconds", "3.5", "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and not result["fell"]
    assert result["steps"] >= 5 and result["distance"][0] > 0.4
    assert result["mean_velocity"][0] == pytest.approx(0.3, abs=0.1)
    assert result["wbc_tick_single_support_median_us"] > 0
    # Tracking both ways over the same steps: every tick's instantaneous velocity carries the sway that per-step averages remove.
    assert 0 < result["tracking_rms_per_step"] < result["tracking_rms_per_tick_heading_xy"] < 0.4
    assert 0 < result["tracking_mean_abs_per_tick_heading_xy"] <= result["tracking_rms_per_tick_heading_xy"]
    assert 0 < result["yaw_rate_mean_abs_per_tick"] <= result["yaw_rate_rms_per_tick"]


def test_walk_clamps_a_command_beyond_the_limits_and_refuses_nan(capsys):
    code = main(["walk", "--vx", "5", "--seconds", "1.0", "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and any("vx = 5" in note and "clamped" in note for note in result["notes"])
    followed, notes = followed_command((5.0, 0.0, 0.0))  # the walker's own clamp (FootstepPlanner at its gait)
    assert notes and followed[0] < 5.0  # no gait of a G1 walks 5 m/s
    assert result["command_clamped"] and result["command"][0] == 5.0 and result["command_followed"][0] == pytest.approx(followed[0], abs=1e-4)
    with pytest.raises(SystemExit) as refused:
        main(["walk", "--vx", "nan", "--seconds", "1.0"])
    assert refused.value.code == 2 and "finite" in capsys.readouterr().err


def test_walk_says_which_command_it_followed_and_no_speed_without_a_step(capsys):
    assert main(["walk", "--vx", "5", "--seconds", "0.5"]) == 0
    out = capsys.readouterr().out
    followed = tuple(round(x, 4) for x in followed_command((5.0, 0.0, 0.0))[0])
    assert f"= {followed} m/s, m/s, rad/s (clamped to the gait's limits from (5.0, 0.0, 0.0))" in out
    assert "speed n/a (no complete step)" in out and "None" not in out


def test_walk_refuses_a_fixed_base_robot_and_a_push_after_the_end(capsys):
    assert main(["walk", "--robot", "cartpole", "--seconds", "1"]) == 2
    assert "fixed base" in capsys.readouterr().err
    assert main(["walk", "--push", "50", "--push-time", "5", "--seconds", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "must end within" in err


def test_walk_streamed_to_foxglove_runs_at_real_time(capsys):
    pytest.importorskip("foxglove")
    assert main(["walk", "--foxglove", "--foxglove-port", "18731", "--seconds", "1.5", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["seconds"] == pytest.approx(1.5, abs=0.01) and result["wall_seconds"] >= 1.4  # a viewer can follow
