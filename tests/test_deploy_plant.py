"""``giwbc deploy --emulate --plant``: the emulated robot runs a plant the controller was not
built on (a shipped variant, a variant file, an MJCF), checked before anything starts."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from giwbc.apps.deploy import DeployOptions, add_deploy_command, deploy, deploy_options
from giwbc.errors import ConfigError
from giwbc.plants import resolve_plant
from giwbc.runtimes.phases import StartupConfig

QUICK = StartupConfig(settle_time=0.05, ramp_time=0.3, shutdown_time=0.1, off_delay=0.05)


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="giwbc")
    add_deploy_command(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["deploy", *argv])


def test_a_plant_needs_the_emulator():
    with pytest.raises(ConfigError, match="--plant .* needs --emulate"):
        deploy_options(parse("--plant", "lagged_actuators"))
    with pytest.raises(ConfigError, match="plant must be"):
        DeployOptions(emulate=True, plant="  ")
    assert deploy_options(parse("--emulate", "--plant", "lagged_actuators")).plant == "lagged_actuators"


def test_an_unknown_plant_is_refused_in_one_line_before_anything_starts(g1, tmp_path):
    options = DeployOptions(emulate=True, controller="pd", seconds=0.1, realtime=False, plant="no_such_plant", log=str(tmp_path / "x.mcap"))
    outcome = deploy(options, description=g1, out=None)
    assert outcome.exit_code == 2 and outcome.result is None and outcome.emulator is None
    assert "no_such_plant" in outcome.message and "frictional_joints" in outcome.message and "\n" not in outcome.message
    assert not (tmp_path / "x.mcap").exists()  # nothing was logged: nothing started
    missing = DeployOptions(emulate=True, controller="pd", seconds=0.1, realtime=False, plant=str(tmp_path / "absent.toml"))
    assert deploy(missing, description=g1, out=None).exit_code == 2


def test_the_emulated_robot_is_the_variant_and_the_wbc_holds_it(g1, tmp_path):
    """frictional_joints: dry friction and damping in every joint, armature off by ~2x (the
    controller keeps robot.toml's); the whole-body controller on the estimate stands on it."""
    lines: list[str] = []
    options = DeployOptions(emulate=True, controller="wbc", seconds=1.0, realtime=False, plant="frictional_joints", startup=QUICK,
                            log=str(tmp_path / "plant.mcap"), scene_rate=0.0)  # fmt: skip
    outcome = deploy(options, description=g1, out=lines.append)
    assert outcome.exit_code == 0, outcome.message
    model = outcome.emulator.robot.model
    variant = resolve_plant(g1, "frictional_joints").model
    nominal = g1.build_mujoco()
    assert np.array_equal(model.dof_frictionloss, variant.dof_frictionloss) and model.dof_frictionloss.max() >= 1.0
    assert nominal.dof_frictionloss.max() == 0.0  # the controller's own model has none
    assert not np.allclose(model.dof_armature, nominal.dof_armature)
    assert outcome.standing["stood"] and outcome.standing["max_tilt"] < np.radians(5)
    assert any("emulated plant: frictional_joints" in line for line in lines)
