"""The floating-point kernels are pinned on x86-64 (giwbc.numerics): a seed's rollout then does not
depend on whether the CPU has AVX-512 (the tests' closed-loop outcomes were measured with the AVX2
kernels; on an AVX-512 machine the default ones turn a 50 N push episode into another)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from giwbc.numerics import AVX2_KERNELS, _has_avx2, blas_core, pin_kernels


def test_pin_kernels_sets_what_the_user_left_unset():
    environ = {"MKL_CBWR": "COMPATIBLE"}
    chosen = pin_kernels(environ, avx2=True)
    assert environ == {**AVX2_KERNELS, "MKL_CBWR": "COMPATIBLE"}  # the user's choice stays
    assert chosen == {k: v for k, v in AVX2_KERNELS.items() if k != "MKL_CBWR"}


def test_pin_kernels_leaves_other_machines_alone():
    environ: dict[str, str] = {}
    assert pin_kernels(environ, avx2=False) == {} and environ == {}


@pytest.mark.skipif(not _has_avx2(), reason="not an x86-64 machine with AVX2: the libraries keep their own kernels")
def test_importing_giwbc_first_gives_numpy_the_avx2_blas_kernels():
    environ = {k: v for k, v in os.environ.items() if k not in AVX2_KERNELS}
    code = "import giwbc, numpy; from giwbc.numerics import blas_core; print(blas_core())"
    out = subprocess.run([sys.executable, "-c", code], env=environ, capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "Haswell"
    if os.environ.get("OPENBLAS_CORETYPE", "Haswell") == "Haswell":  # this process too (conftest imports giwbc first)
        assert blas_core() == "Haswell"
