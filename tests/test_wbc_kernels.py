"""The WBC assembly's compiled kernel (issue 37, :mod:`giwbc.control.kernels`) against its uncompiled
Python function and the numpy formulation it replaces, bit for bit, on random inputs and on the
G1 controller's own layout (a strided block of ``[A; C]``, Pinocchio's Fortran-ordered ``M``)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from giwbc.control import kernels, make_balance_controller
from giwbc.robot import load


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "python"])
def test_the_dynamics_rows_are_the_numpy_ones_bit_for_bit(compiled: bool) -> None:
    kernel = kernels.dynamics_rows if compiled else kernels.reference(kernels.dynamics_rows)
    rng = np.random.default_rng(3720)
    for trial in range(40):
        nv, nb = int(rng.integers(3, 40)), int(rng.choice([0, 6])) if trial % 2 else 6
        nb = min(nb, nv - 1)
        M = rng.normal(size=(nv, nv))
        M = np.asfortranarray(M) if trial % 3 else M
        h = rng.normal(0.0, 100.0, nv)
        tau = rng.uniform(1.0, 200.0, nv - nb)
        AC = np.full((nv + 4, nv + 12), np.nan)
        D_M = AC[2 : 2 + nv, :nv]  # a strided view, as the controller's
        limits = np.full((2, nv - nb + 3), np.nan)
        b = np.full(nb + 2, np.nan)
        kernel(D_M, M, h, b[2:], -tau, tau, limits[0, : nv - nb], limits[1, : nv - nb])
        assert D_M.tobytes() == np.ascontiguousarray(M).tobytes()
        assert b[2:].tobytes() == np.negative(h[:nb]).tobytes()
        assert limits[0, : nv - nb].tobytes() == np.subtract(-tau, h[nb:]).tobytes()
        assert limits[1, : nv - nb].tobytes() == np.subtract(tau, h[nb:]).tobytes()
        assert np.isnan(AC[:2]).all() and np.isnan(AC[2 : 2 + nv, nv:]).all() and np.isnan(b[:2]).all()  # nothing else written
        assert np.isnan(limits[:, nv - nb :]).all()


def test_the_g1_controller_compiles_its_kernel_once_at_construction() -> None:
    """The warm-up compiles the layouts the G1's ticks pass: a tick adds no specialization (no
    compile in a control loop), and the problem's torque rows hold ``τ_max − h_j``."""
    controller = make_balance_controller(load("g1"))
    known = len(kernels.dynamics_rows.signatures)
    wbc = controller.wbc
    result = controller.update(pin.neutral(wbc.model), np.zeros(wbc.nv), 0.0)
    assert result.ok
    assert len(kernels.dynamics_rows.signatures) == known
    h = wbc.kin.nonlinear_effects
    np.testing.assert_array_equal(wbc._u_torque, wbc.torque_limits - h[wbc.n_base :])
    np.testing.assert_array_equal(wbc.problem.b[-wbc.n_base :], -h[: wbc.n_base])
