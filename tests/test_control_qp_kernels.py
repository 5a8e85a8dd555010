"""The active-set guess's compiled KKT kernels (issue 37, :mod:`giwbc.control.qp.kernels`) against their
uncompiled Python functions and against the numpy formulation they replace, bit for bit, on random
inputs; the KKT system they assemble solved by LAPACK is the QP's optimum."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import lapack

from giwbc.control.qp import kernels

KERNELS = {"compiled": (kernels.kkt_fill, kernels.kkt_check), "python": (kernels.reference(kernels.kkt_fill), kernels.reference(kernels.kkt_check))}


def _random_system(rng: np.random.Generator, fixed: bool) -> dict:
    """A random problem of the guess's layout: ``stack = [A; C]`` (ne + ni rows), limits ``[lo; hi]``,
    an active set of inequality rows, optionally a few fixed variables eliminated."""
    n, ne, ni = int(rng.integers(6, 14)), int(rng.integers(1, 4)), int(rng.integers(3, 12))
    root = rng.normal(size=(n, n))
    H = root @ root.T + np.eye(n)
    g = rng.normal(size=n)
    stack = rng.normal(size=(ne + ni, n))
    lo = np.concatenate([np.zeros(ne), -rng.uniform(0.1, 1.0, ni)])
    hi = np.concatenate([np.zeros(ne), rng.uniform(0.1, 1.0, ni)])
    lo[:ne] = hi[:ne] = rng.normal(size=ne)
    pinned = rng.integers(0, ni, 2) + ne
    lo[pinned] = hi[pinned]  # rows pinned at l = u: their multipliers' signs are free
    keep = np.sort(rng.choice(n, n - 2, replace=False)) if fixed else np.arange(n)
    active = np.sort(rng.choice(ni, int(rng.integers(0, min(ni, len(keep) - ne) + 1)), replace=False))
    upper = rng.random(len(active)) < 0.5
    rows_a = ne + active
    limits = np.concatenate([lo, hi])
    return {
        "n": n, "ne": ne, "H": H, "g": g, "stack": stack, "lo": lo, "hi": hi, "limits": limits, "keep": keep,
        "eq_rows": np.concatenate([np.arange(ne), rows_a]), "rhs_index": np.concatenate([np.arange(ne), rows_a + len(lo) * upper]),
        "rows_a": rows_a, "sign_open": 1.0 - 2.0 * upper,
    }


def _numpy_fill(s: dict, diagonal: float) -> tuple[np.ndarray, np.ndarray]:
    """The former numpy assembly of the KKT system."""
    keep, E = s["keep"], s["stack"][s["eq_rows"]][:, s["keep"]]
    n, m = len(keep), len(s["eq_rows"])
    K = np.zeros((n + m, n + m))
    K[:n, :n] = s["H"][np.ix_(keep, keep)]
    K[n:, :n] = E
    K[:n, n:] = E.T
    K[n:, n:].flat[:: m + 1] = diagonal
    return K, np.concatenate([-s["g"][keep], s["limits"][s["rhs_index"]]])


def _numpy_check(s: dict, r: np.ndarray, multipliers: np.ndarray, signs: bool) -> tuple[float, np.ndarray]:
    """The former numpy check: over, under, signed multipliers and the first maximum's value."""
    lo, hi, rows_a = s["lo"], s["hi"], s["rows_a"]
    parts = [r - hi, lo - r]
    if signs:
        parts.append(multipliers * np.where(lo[rows_a] + 0.0 == hi[rows_a], 0.0, s["sign_open"]))
    checked = np.concatenate(parts)
    return (float(checked[checked.argmax()]) if len(checked) else -np.inf), checked


@pytest.mark.parametrize("mode", list(KERNELS))
@pytest.mark.parametrize("fixed", [False, True], ids=["all_variables", "fixed_eliminated"])
def test_the_kkt_assembly_is_the_numpy_one_bit_for_bit_and_solves_to_a_kkt_point(mode: str, fixed: bool) -> None:
    fill, _ = KERNELS[mode]
    rng = np.random.default_rng(3700 + fixed)
    for _ in range(50):
        s = _random_system(rng, fixed)
        diagonal = float(rng.choice([0.0, -1e-12]))
        size = len(s["keep"]) + len(s["eq_rows"])
        K, rhs = np.full((size, size), np.nan), np.full(size, np.nan)  # every entry must be written
        fill(K, rhs, s["H"], s["g"], s["stack"], s["keep"], s["eq_rows"], s["limits"], s["rhs_index"], diagonal)
        K_ref, rhs_ref = _numpy_fill(s, diagonal)
        assert K.tobytes() == K_ref.tobytes() and rhs.tobytes() == rhs_ref.tobytes()
        # Solved as the guess solves it: stationarity H x + g + Eᵀ(-λ) = 0 and the active rows at their limits.
        _, _, solution, info = lapack.dgesv(K.T, rhs, overwrite_a=1, overwrite_b=0)
        assert info == 0
        n, keep = len(s["keep"]), s["keep"]
        x = solution[:n]
        E = s["stack"][s["eq_rows"]][:, keep]
        np.testing.assert_allclose(E @ x, s["limits"][s["rhs_index"]], atol=1e-8)
        np.testing.assert_allclose(s["H"][np.ix_(keep, keep)] @ x + E.T @ solution[n:] + s["g"][keep], 0.0, atol=1e-8)


@pytest.mark.parametrize("mode", list(KERNELS))
def test_the_optimality_check_is_the_numpy_one_bit_for_bit(mode: str) -> None:
    _, check_kernel = KERNELS[mode]
    rng = np.random.default_rng(3711)
    for trial in range(200):
        s = _random_system(rng, fixed=bool(trial % 2))
        rows, k = len(s["lo"]), len(s["rows_a"])
        r = rng.normal(size=rows)
        multipliers = rng.normal(size=k)
        if trial % 7 == 0:
            (r if trial % 2 else multipliers if k else r)[0] = np.nan  # a singular system's NaN reaches the verdict
        signs = bool(trial % 3)
        check = np.full(2 * rows + k, np.inf)
        worst = check_kernel(r, s["lo"], s["hi"], check, s["rows_a"], s["sign_open"], multipliers, signs)
        worst_ref, checked_ref = _numpy_check(s, r, multipliers, signs)
        assert np.isnan(worst) == np.isnan(worst_ref)
        if not np.isnan(worst_ref):
            assert worst == worst_ref
        written = 2 * rows + (k if signs else 0)
        assert check[:written].tobytes() == checked_ref.tobytes()
        assert np.all(check[written:] == np.inf)  # nothing past what it checks


def test_nothing_to_check_is_minus_infinity() -> None:
    _, check_kernel = KERNELS["compiled"]
    empty = np.zeros(0)
    assert check_kernel(empty, empty, empty, empty, np.zeros(0, np.int64), empty, empty, True) == -np.inf
