"""The feet's yaw moment bound while a push is caught (WalkerConfig.recovery_torsion): the rows of
every support rewritten in place (SoleSupport.set_torsion), tight while recovering, loose otherwise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from giwbc.control.contacts import wrench_cone_matrix
from giwbc.control.sole import SoleSupport
from giwbc.locomotion.simulation import Push, simulate_walk
from giwbc.locomotion.walker import WalkingController
from giwbc.locomotion.walker_config import TORSION_LOOSE, WalkerConfig, walker_config
from giwbc.robot import load

CORNERS = np.array([[0.07, 0.025], [-0.07, 0.025], [-0.07, -0.025], [0.07, -0.025]])


@pytest.fixture(scope="module")
def g1():
    return load("g1")


def _inside(support: SoleSupport, mode: int, wrench: np.ndarray) -> bool:
    return bool((support.matrices[mode, : support.counts[mode]] @ wrench).max() <= 1e-12)


def test_set_torsion_rewrites_the_yaw_rows_of_every_support() -> None:
    cone = wrench_cone_matrix(0.07, 0.025, 0.8)
    support = SoleSupport(CORNERS, 0.8, full_rows=cone, torsion=TORSION_LOOSE)
    rows, counts = support.n_rows, list(support.counts)
    support.set_torsion(0.005)
    assert support.n_rows == rows and support.counts == counts  # the QP's shape is kept
    np.testing.assert_allclose(support.matrices, SoleSupport(CORNERS, 0.8, full_rows=cone, torsion=0.005).matrices, atol=1e-15)
    for mode, piece in enumerate(support.modes):
        centre = piece.polygon.mean(axis=0)
        wrench = np.array([0.0, 0.0, 100.0, 100.0 * centre[1], -100.0 * centre[0], 0.0])
        assert _inside(support, mode, wrench + [0, 0, 0, 0, 0, 0.4])  # 0.4 N m < 0.005 m x 100 N
        assert not _inside(support, mode, wrench + [0, 0, 0, 0, 0, 0.6])
    support.set_torsion(TORSION_LOOSE)  # back: the sole's friction alone bounds it (7.6 N m at 100 N)
    assert _inside(support, 0, np.array([0.0, 0.0, 100.0, 0.0, 0.0, 5.0]))
    with pytest.raises(ValueError, match="torsion"):
        SoleSupport(CORNERS, 0.8).set_torsion(0.01)
    with pytest.raises(ValueError, match="torsion"):
        support.set_torsion(-0.01)
    with pytest.raises(ValueError, match="recovery_torsion"):
        WalkerConfig(recovery_torsion=0.0)


def test_the_walker_bounds_the_yaw_moment_only_while_it_catches_a_push(g1) -> None:
    """Nominal plant, any_floor with recovery_torsion 0.005 m, 100 N x 0.2 s from the side: while the
    walker recovers every loaded foot's planned |tau_z| stays within 0.005 m x f_z; standing before
    and after, the feet are back at the loose bound; the push is caught."""
    assert [c.torsion for c in WalkingController(g1, WalkerConfig(recovery_torsion=0.01)).balance.contacts] == [TORSION_LOOSE] * 2
    config = walker_config({"recovery_torsion": 0.005}, walker_config("any_floor"))
    seen = {"tight": 0, "loose_after": False, "worst": 0.0}

    def observe(robot, controller) -> None:
        torsions = {c.torsion for c in controller.contacts.values()}
        assert len(torsions) == 1
        if torsions == {0.005}:
            seen["tight"] += 1
            for wrench in controller.last_result.contact_wrenches.values():
                if wrench[2] > 20.0:
                    seen["worst"] = max(seen["worst"], abs(wrench[5]) / wrench[2])
        elif robot.time() > 3.5:
            seen["loose_after"] = True
        if robot.time() < 2.0:
            assert torsions == {TORSION_LOOSE}

    run = simulate_walk(g1, (0.0, 0.0, 0.0), 4.5, pushes=(Push(2.0, 100.0, math.pi / 2, 0.2),), command_start=None, seed=7,
                        config=config, observe=observe)
    assert not run.fell and run.recovery_steps >= 1
    assert seen["tight"] > 50  # > 0.1 s of recovery under the bound
    assert seen["worst"] <= 0.005 * (1.0 + 1e-6)
    assert seen["loose_after"]
