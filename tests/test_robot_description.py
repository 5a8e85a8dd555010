"""Loading robot descriptions: what ships, and clear errors for bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from giwbc.robot import RobotDescription, RobotDescriptionError, available_robots, load

CARTPOLE_FOLDER = Path(__file__).resolve().parents[1] / "robots" / "cartpole"


def copy_cartpole(tmp_path: Path, config_edit=None, urdf_edit=None) -> Path:
    folder = tmp_path / "robot"
    shutil.copytree(CARTPOLE_FOLDER, folder)
    for name, edit in [("robot.toml", config_edit), ("cartpole.urdf", urdf_edit)]:
        if edit is not None:
            path = folder / name
            path.write_text(edit(path.read_text()))
    return folder


def test_shipped_robots() -> None:
    assert {"g1", "cartpole"} <= set(available_robots())


def test_g1_description(g1: RobotDescription) -> None:
    assert g1.floating_base and g1.dofs == 29
    assert g1.joint_names[0] == "left_hip_pitch_joint" and g1.joint_names[-1] == "right_wrist_yaw_joint"
    assert g1.total_mass == pytest.approx(33.34, abs=0.01)
    assert g1.effort_limits[g1.joint_names.index("left_knee_joint")] == 139.0
    assert {c.name for c in g1.contacts} == {"left_foot", "right_foot"}
    lower, upper = g1.position_limits
    assert np.all((lower <= g1.default_positions) & (g1.default_positions <= upper))


def test_cartpole_description(cartpole: RobotDescription) -> None:
    assert not cartpole.floating_base
    assert cartpole.joint_names == ("linear", "pivot")
    assert cartpole.actuated.tolist() == [True, False]
    assert cartpole.effort_limits.tolist() == [50.0, 0.0]


def test_load_by_path(tmp_path: Path) -> None:
    folder = copy_cartpole(tmp_path)
    assert load(folder).name == "cartpole"
    assert load(folder / "robot.toml").name == "cartpole"


def test_unknown_robot_names_the_available_ones() -> None:
    with pytest.raises(RobotDescriptionError, match="unknown robot 'nao'.*g1"):
        load("nao")


def test_missing_config_file(tmp_path: Path) -> None:
    with pytest.raises(RobotDescriptionError, match="missing file"):
        load(tmp_path)


def test_missing_model_file(tmp_path: Path) -> None:
    folder = copy_cartpole(tmp_path)
    (folder / "cartpole.urdf").unlink()
    with pytest.raises(RobotDescriptionError, match="cartpole.urdf does not exist"):
        load(folder)


def test_malformed_toml(tmp_path: Path) -> None:
    folder = copy_cartpole(tmp_path, config_edit=lambda text: text + "\n[joints\n")
    with pytest.raises(RobotDescriptionError, match="invalid TOML"):
        load(folder)


def test_malformed_urdf(tmp_path: Path) -> None:
    folder = copy_cartpole(tmp_path, urdf_edit=lambda text: text.replace("</robot>", ""))
    with pytest.raises(RobotDescriptionError, match="malformed URDF"):
        load(folder)


def test_joint_the_model_lacks(tmp_path: Path) -> None:
    folder = copy_cartpole(tmp_path, config_edit=lambda text: text + 'elbow = { default = 0.0 }\n')
    with pytest.raises(RobotDescriptionError, match="joint 'elbow' is listed in the config but the model"):
        load(folder)


def test_joint_the_config_lacks(tmp_path: Path) -> None:
    folder = copy_cartpole(tmp_path, config_edit=lambda text: text.replace("pivot  = {", "# pivot = {"))
    with pytest.raises(RobotDescriptionError, match="joints the config does not list: \\['pivot'\\]"):
        load(folder)


def test_wrong_types_and_values(tmp_path: Path) -> None:
    folder = copy_cartpole(tmp_path, config_edit=lambda text: text.replace("kp = 0.0", 'kp = "stiff"', 1))
    with pytest.raises(RobotDescriptionError, match="'kp' should be a finite number"):
        load(folder)
    folder = copy_cartpole(tmp_path / "b", config_edit=lambda text: text.replace('base_link = "rail"', 'base_link = "track"'))
    with pytest.raises(RobotDescriptionError, match="base_link 'track' is not a link"):
        load(folder)


def test_joint_order_mismatch_is_explained(tmp_path: Path) -> None:
    def swap(text: str) -> str:
        lines = text.splitlines()
        i, j = next(k for k, l in enumerate(lines) if l.startswith("linear")), next(k for k, l in enumerate(lines) if l.startswith("pivot"))
        lines[i], lines[j] = lines[j], lines[i]
        return "\n".join(lines) + "\n"

    description = load(copy_cartpole(tmp_path, config_edit=swap))
    with pytest.raises(RobotDescriptionError, match="joint order differs.*\\['linear', 'pivot'\\]"):
        description.build_pinocchio()
    with pytest.raises(RobotDescriptionError, match="joint order differs"):
        description.build_mujoco()


def test_one_pinocchio_model_per_description(monkeypatch) -> None:
    """The URDF is parsed once per description: the controller, the safety checks and the estimator
    share it (each with its own Data); build_pinocchio() hands out independent copies."""
    import pinocchio as pin

    import giwbc.robot.description as description_module
    from giwbc.control.balance import make_balance_controller
    from giwbc.estimation.estimator import StateEstimator
    from giwbc.hal.safety import SafetyConfig, SafetySupervisor

    parses = []
    original = description_module.build_pinocchio_model
    monkeypatch.setattr(description_module, "build_pinocchio_model", lambda d: parses.append(d) or original(d))
    g1 = load("g1")
    make_balance_controller(g1)
    SafetySupervisor(g1, SafetyConfig())
    StateEstimator(g1)
    assert len(parses) == 1 and g1.pinocchio_model is g1.pinocchio_model
    copy = g1.build_pinocchio()
    assert copy is not g1.pinocchio_model and copy.nq == g1.pinocchio_model.nq
    copy.inertias[1] = pin.Inertia.Zero()
    assert g1.pinocchio_model.inertias[1].mass > 0  # the shared model is untouched


def test_imu_in_base_is_the_urdf_mount(g1) -> None:
    """The G1's imu_in_pelvis joint: (0.04525, 0, -0.08339) m in the pelvis, axes aligned."""
    placement = g1.imu_in_base
    np.testing.assert_allclose(placement.translation, [0.04525, 0.0, -0.08339], atol=1e-9)
    np.testing.assert_allclose(placement.rotation, np.eye(3), atol=1e-12)
