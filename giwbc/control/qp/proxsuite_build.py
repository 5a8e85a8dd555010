"""Which of proxsuite's compiled builds giwbc solves with: the baseline (SSE2) one, for reproducibility.

proxsuite ships three builds of one extension (``proxsuite_pywrap``, ``_avx2``, ``_avx512``) and
its package ``__init__`` imports the widest one the CPU runs. The AVX2 and AVX-512 builds give
iterates whose last bits depend on where the heap put proxsuite's workspace: measured on G1Walk,
the same 30 recorded QPs, solved with fresh solvers in one process, changed bits in all 30 after
three environment steps and back again later; the baseline build, whose 16-byte vectors glibc
always aligns, changed none (``tests/test_wbc_determinism.py``). Most answers are then polished
into exact, deterministic ones (:class:`~giwbc.control.qp.active_set.ActiveSetGuess`), but where
the polish fails (a falling robot) the answer follows proxsuite's bits, and an environment used
for some episodes, a resumed training run or another machine stopped repeating a rollout bit for
bit. The baseline build also gives the same bits on every x86-64 CPU. Its cost: ~10 % more per
proxsuite solve, on the ~1 in 10 ticks the guess misses (``benchmarks/wbc_tick.py``).

The choice is made once per process, when giwbc first needs proxsuite (or qpsolvers, which
imports proxsuite). A process that imported proxsuite itself first keeps the build it loaded,
with a :class:`ReproducibilityWarning`.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types
import warnings

BASELINE = "proxsuite.proxsuite_pywrap"


class ReproducibilityWarning(RuntimeWarning):
    """Results of this process may not repeat bit for bit elsewhere (or later in it)."""


def build_name(package: types.ModuleType) -> str:
    """The compiled build a loaded proxsuite package dispatches to (``proxsuite.proxsuite_pywrap…``)."""
    submodule = getattr(package, "_submodule", None)
    return getattr(submodule, "__name__", "unknown")


def load_proxsuite() -> types.ModuleType:
    """The ``proxsuite`` package, dispatching to its baseline build when giwbc loads it first.

    proxsuite's ``__init__`` asks ``proxsuite.instructionset`` which build to import; it is
    imported here with that probe answering "no AVX" (the same path proxsuite takes on a CPU
    without AVX). Afterwards ``import proxsuite`` anywhere in the process returns this package.
    """
    package = sys.modules.get("proxsuite")
    if package is None:
        spec = importlib.util.find_spec("proxsuite")
        if spec is None or spec.loader is None:
            raise ModuleNotFoundError("proxsuite is not installed (pip install 'proxsuite>=0.6,<0.9')")
        probe = types.ModuleType("proxsuite.instructionset")
        probe.has_AVX512F = probe.has_AVX2 = lambda: False  # type: ignore[attr-defined]
        package = importlib.util.module_from_spec(spec)
        sys.modules["proxsuite"] = package
        sys.modules["proxsuite.instructionset"] = probe
        try:
            spec.loader.exec_module(package)
        except BaseException:
            del sys.modules["proxsuite"]
            raise
        finally:
            del sys.modules["proxsuite.instructionset"]  # a later import gets the real probe
    name = build_name(package)
    if name != BASELINE:
        warnings.warn(
            f"proxsuite was imported before giwbc and loaded its build {name!r}, whose results depend on "
            f"the heap's history: import giwbc's controllers (or giwbc.control.qp.proxsuite_build."
            f"load_proxsuite()) before proxsuite or qpsolvers for bit-reproducible rollouts",
            ReproducibilityWarning,
            stacklevel=2,
        )
    return package


def import_qpsolvers() -> types.ModuleType:
    """``qpsolvers``, imported after :func:`load_proxsuite` (qpsolvers imports proxsuite)."""
    load_proxsuite()
    return importlib.import_module("qpsolvers")
