"""One set of floating-point kernels on every x86-64 machine, so a seed gives the same rollout on
each: numpy's OpenBLAS, torch's ATen and its MKL pick their kernels by CPU when they load (AVX-512
ones on a machine that has it), and those kernels round differently, which a closed loop with
contacts turns into another trajectory within a second. :func:`pin_kernels` asks for the AVX2 ones
(the widest every x86-64 machine this project has run on offers) unless the user chose already.

It must run before numpy or torch load: ``import giwbc`` calls it first, and the test suite's
conftest imports giwbc before numpy. A process that loaded numpy earlier keeps its kernels;
:func:`blas_core` tells which it got.
"""

from __future__ import annotations

import ctypes
import os
import platform
from collections.abc import MutableMapping
from pathlib import Path

# Environment variables the libraries read when they load, and the AVX2 choice of each.
AVX2_KERNELS = {"OPENBLAS_CORETYPE": "Haswell", "ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "AVX2"}


def _has_avx2(cpuinfo: Path = Path("/proc/cpuinfo")) -> bool:
    """Whether this is an x86-64 Linux machine whose CPU has AVX2 and FMA (the Haswell kernels' needs)."""
    if platform.machine().lower() not in ("x86_64", "amd64") or not cpuinfo.is_file():
        return False
    for line in cpuinfo.read_text(errors="replace").splitlines():
        if line.startswith("flags"):
            flags = set(line.split(":", 1)[1].split())
            return {"avx2", "fma"} <= flags
    return False


def pin_kernels(environ: MutableMapping[str, str] | None = None, *, avx2: bool | None = None) -> dict[str, str]:
    """Set each of :data:`AVX2_KERNELS` the user has not set, on an x86-64 machine with AVX2;
    return what was set (nothing elsewhere: other machines keep their libraries' own choice)."""
    environ = os.environ if environ is None else environ
    if not (_has_avx2() if avx2 is None else avx2):
        return {}
    chosen = {key: value for key, value in AVX2_KERNELS.items() if key not in environ}
    environ.update(chosen)
    return chosen


def blas_core() -> str | None:
    """The OpenBLAS core numpy's BLAS runs on (``"Haswell"``, ``"SkylakeX"``, ...), or None when
    numpy uses another BLAS or the name cannot be read."""
    import numpy

    folder = Path(numpy.__file__).resolve().parent.parent / "numpy.libs"
    for library in sorted(folder.glob("*openblas*")) if folder.is_dir() else ():
        try:
            handle = ctypes.CDLL(str(library))
        except OSError:
            continue
        for symbol in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename", "openblas_get_corename64_",
                       "openblas_get_corename"):
            function = getattr(handle, symbol, None)
            if function is not None:
                function.restype = ctypes.c_char_p
                name = function()
                return name.decode() if name else None
    return None

