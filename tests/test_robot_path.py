"""The robot search path and robot.toml keys: a typo is refused with the key and the file, a broken
robot never hides the others, a GIWBC_ROBOT_PATH folder that does not exist is an error, and
`giwbc robots` with no robot is an error (exit 2), not an empty table."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import giwbc.robot.description as description_module
from giwbc.apps.cli import main
from giwbc.robot import RobotDescriptionError, load
from giwbc.robot.description import available_robots, robot_search_path, scan_robots

CARTPOLE = Path(__file__).resolve().parents[1] / "robots" / "cartpole"


def robot_folder(parent: Path, name: str, edit=None) -> Path:
    """A copy of the cart-pole in ``parent/name``, its robot.toml passed through ``edit``."""
    folder = parent / name
    shutil.copytree(CARTPOLE, folder)
    if edit is not None:
        config = folder / "robot.toml"
        config.write_text(edit(config.read_text()))
    return folder


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('base_link = "rail"', 'base_link = "rail"\nimu_frme = "rail"'),
         r"robot\.toml \[model\]: unknown key 'imu_frme' \(did you mean 'imu_frame'\?\)$"),
        (lambda t: t.replace("[simulation]", "[simulaton]"),
         r"robot\.toml: unknown key 'simulaton' \(did you mean 'simulation'\?\)$"),
        (lambda t: t.replace("timestep = 0.001", "time_step = 0.001"),
         r"robot\.toml \[simulation\]: unknown key 'time_step' \(did you mean 'timestep'\?\)$"),
        (lambda t: t.replace("kd = 0.0 }", "kd = 0.0, damping = 1.0 }", 1),
         r"robot\.toml joint 'linear': unknown key 'damping' \(known keys: actuated, armature, default, kd, kp\)$"),
        (lambda t: t.replace("floating_base = false", 'floating_base = "false"'),
         r"robot\.toml \[model\]: 'floating_base' should be true or false, got 'false'$"),
        (lambda t: t.replace("actuated = false", 'actuated = "no"'),
         r"robot\.toml joint 'pivot': 'actuated' should be true or false, got 'no'$"),
    ],
)
def test_a_misspelled_or_mistyped_key_is_refused_with_the_file(tmp_path: Path, edit, message: str) -> None:
    folder = robot_folder(tmp_path, "cartpole", edit)
    with pytest.raises(RobotDescriptionError, match=message) as caught:
        load(folder)
    assert str(caught.value).startswith(str(folder / "robot.toml"))
    assert "\n" not in str(caught.value)


def test_a_misspelled_imu_frame_no_longer_leaves_the_g1_without_one(tmp_path: Path) -> None:
    g1 = load("g1")
    config = (g1.folder / "robot.toml").read_text()
    assert g1.imu_frame == "imu_in_pelvis"
    folder = tmp_path / "g1"
    shutil.copytree(g1.folder, folder)
    (folder / "robot.toml").write_text(config.replace("imu_frame =", "imu_frme ="))
    with pytest.raises(RobotDescriptionError, match=r"unknown key 'imu_frme' \(did you mean 'imu_frame'\?\)"):
        load(folder)


def test_one_broken_robot_never_hides_the_others(tmp_path: Path, monkeypatch, capsys) -> None:
    robot_folder(tmp_path, "good")
    broken = robot_folder(tmp_path, "broken", lambda t: t.replace("[joints]", "[joints"))  # invalid TOML
    typo = robot_folder(tmp_path, "typo", lambda t: t.replace("[model]", "[modle]"))
    monkeypatch.setenv("GIWBC_ROBOT_PATH", str(tmp_path))

    assert {"good", "broken", "typo", "g1", "cartpole"} <= set(available_robots())
    loaded, failed = scan_robots()
    assert {d.folder.name for d in loaded} >= {"good", "g1", "cartpole"}
    assert {f.name: f.config for f in failed} == {"broken": broken / "robot.toml", "typo": typo / "robot.toml"}
    with pytest.raises(RobotDescriptionError, match="invalid TOML"):
        load("broken")  # loading it by name gives its own error
    assert load("good").dofs == 2

    assert main(["robots"]) == 0
    out, err = capsys.readouterr()
    listed = [line.split()[0] for line in out.splitlines()[1:]]
    assert set(listed) == {"good", "g1", "cartpole"}
    warnings = err.splitlines()
    assert len(warnings) == 2 and all(w.startswith("giwbc robots: warning: skipped robot") for w in warnings)
    assert any(f"{broken / 'robot.toml'}: invalid TOML" in w for w in warnings)
    assert any(f"{typo / 'robot.toml'}: unknown key 'modle' (did you mean 'model'?)" in w for w in warnings)


def test_a_robot_path_folder_that_does_not_exist_is_an_error(tmp_path: Path, monkeypatch, capsys) -> None:
    missing = tmp_path / "robts"
    monkeypatch.setenv("GIWBC_ROBOT_PATH", f"{tmp_path}:{missing}")
    with pytest.raises(RobotDescriptionError, match=rf"^GIWBC_ROBOT_PATH entry '{missing}' does not exist"):
        robot_search_path()
    with pytest.raises(RobotDescriptionError, match="does not exist"):
        load("g1")
    assert load(CARTPOLE).name == "cartpole"  # a path needs no search path
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("GIWBC_ROBOT_PATH", str(tmp_path / "file"))
    assert main(["robots"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "GIWBC_ROBOT_PATH entry" in err and "is not a folder" in err


def test_no_robot_at_all_is_an_error_not_an_empty_list(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(description_module, "shipped_folder", lambda kind: None)  # as an install without its data
    monkeypatch.setenv("GIWBC_ROBOT_PATH", str(tmp_path))
    assert main(["robots"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "no robots: none found in" in err
    robot_folder(tmp_path, "broken", lambda t: t.replace('name = "cartpole"', ""))
    assert main(["robots"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("giwbc robots: warning: skipped robot 'broken'") and "missing required key 'name'" in err[0]
    assert "none of the 1 found loads" in err[1]
    with pytest.raises(RobotDescriptionError, match="unknown robot 'g1'; available robots: broken"):
        load("g1")
