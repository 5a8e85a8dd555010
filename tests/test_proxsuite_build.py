"""Which proxsuite build giwbc solves with (:mod:`giwbc.control.qp.proxsuite_build`), in this process.

The import order across fresh processes is tested in ``tests/test_wbc_determinism.py`` (slow,
subprocesses); these tests take proxsuite out of ``sys.modules`` for a moment (restored after each
test) to load it again the way giwbc does, and check what that load leaves behind.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
import types
import warnings
from pathlib import Path

import pytest

from giwbc.control.qp.proxsuite_build import BASELINE, ReproducibilityWarning, build_name, import_qpsolvers, load_proxsuite


def _forget_proxsuite(monkeypatch: pytest.MonkeyPatch) -> types.ModuleType:
    """Take the loaded proxsuite package (and any probe) out of ``sys.modules`` until the test ends."""
    loaded = load_proxsuite()
    monkeypatch.delitem(sys.modules, "proxsuite")
    monkeypatch.delitem(sys.modules, "proxsuite.instructionset", raising=False)
    return loaded


def test_giwbc_uses_proxsuites_baseline_build_once_per_process() -> None:
    """The package giwbc solves with dispatches to the baseline build, is the one ``import
    proxsuite`` returns, and a second call loads nothing again (no warning either)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        package = load_proxsuite()
        assert load_proxsuite() is package
    import proxsuite

    assert proxsuite is package is sys.modules["proxsuite"]
    assert build_name(package) == BASELINE
    assert package.proxqp.dense.QP is sys.modules[BASELINE].proxqp.dense.QP


def test_loading_asks_for_the_baseline_build_and_leaves_no_probe_behind(monkeypatch) -> None:
    """Loaded afresh (as in a new process), proxsuite's dispatch is answered "no AVX": on this
    CPU it would otherwise pick an AVX build. The package is registered for ``import
    proxsuite``, and the "no AVX" probe is gone afterwards (a later import of
    ``proxsuite.instructionset`` gets the real one)."""
    before = _forget_proxsuite(monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        package = load_proxsuite()
    assert package is not before and isinstance(package, types.ModuleType)
    assert sys.modules["proxsuite"] is package
    assert build_name(package) == BASELINE
    assert package.__spec__.name == "proxsuite" and callable(package.proxqp.dense.QP)
    assert "proxsuite.instructionset" not in sys.modules
    assert load_proxsuite() is package


def test_a_failed_load_leaves_no_half_loaded_package(monkeypatch) -> None:
    """proxsuite missing: a clear error. Its ``__init__`` failing: the error goes through, and
    neither the half-run package nor the probe stays in ``sys.modules`` (a retry starts over)."""
    _forget_proxsuite(monkeypatch)
    real_find_spec = importlib.util.find_spec

    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "proxsuite" else real_find_spec(name, *a))
    with pytest.raises(ModuleNotFoundError, match=r"^proxsuite is not installed \(pip install "):
        load_proxsuite()
    assert "proxsuite" not in sys.modules

    seen = {}

    class Broken(importlib.machinery.SourceFileLoader):
        def exec_module(self, module: types.ModuleType) -> None:
            probe = sys.modules["proxsuite.instructionset"]
            seen["probe"] = (probe.has_AVX512F(), probe.has_AVX2(), sys.modules["proxsuite"] is module)
            raise ImportError("broken build")

    spec = importlib.util.spec_from_loader("proxsuite", Broken("proxsuite", __file__))
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: spec if name == "proxsuite" else real_find_spec(name, *a))
    with pytest.raises(ImportError, match="broken build"):
        load_proxsuite()
    assert seen["probe"] == (False, False, True)  # while proxsuite's __init__ ran: "no AVX", package registered
    assert "proxsuite" not in sys.modules and "proxsuite.instructionset" not in sys.modules


def test_a_proxsuite_loaded_before_giwbc_is_kept_with_a_warning_naming_its_build(monkeypatch) -> None:
    """A process that imported proxsuite itself first (its widest build) keeps that package:
    giwbc warns that its results may not repeat, names the build, and points at the caller."""
    _forget_proxsuite(monkeypatch)
    other = types.ModuleType("proxsuite")
    other._submodule = types.ModuleType("proxsuite.proxsuite_pywrap_avx512")  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "proxsuite", other)
    with pytest.warns(ReproducibilityWarning, match="loaded its build 'proxsuite.proxsuite_pywrap_avx512'") as record:
        assert load_proxsuite() is other
    assert len(record) == 1 and Path(record[0].filename).name != "proxsuite_build.py"  # names a caller's line
    assert "load_proxsuite" in str(record[0].message) and "before proxsuite or qpsolvers" in str(record[0].message)


def test_build_name_of_a_package_without_a_build() -> None:
    assert build_name(types.ModuleType("proxsuite")) == "unknown"
    bare = types.ModuleType("proxsuite")
    bare._submodule = object()  # type: ignore[attr-defined]
    assert build_name(bare) == "unknown"


def test_qpsolvers_comes_after_proxsuites_baseline_build(monkeypatch) -> None:
    """``import_qpsolvers`` loads proxsuite first (qpsolvers would import its widest build)."""
    _forget_proxsuite(monkeypatch)
    qpsolvers = import_qpsolvers()
    assert qpsolvers is sys.modules["qpsolvers"] and "proxqp" in qpsolvers.available_solvers
    assert build_name(sys.modules["proxsuite"]) == BASELINE
