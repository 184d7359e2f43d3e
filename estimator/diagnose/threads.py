"""One BLAS thread while diagnose runs.

Diagnose's linear algebra is small (a few hundred parameters, 32 channels, bands of 3): OpenBLAS's thread pool
only adds synchronisation, and on a loaded 2-core machine a 200 x 200 solve took 70 ms with the default pool
against 7 ms with one thread. numpy and scipy each bundle their own OpenBLAS; both are set through their
``*_set_num_threads`` entry points (ctypes, no extra dependency) and restored afterwards.
"""

from __future__ import annotations

import ctypes
from collections.abc import Iterator
from contextlib import contextmanager

_PREFIXES = ("openblas", "scipy_openblas")
_SUFFIXES = ("", "64_")


def _libraries() -> list[tuple[ctypes.CDLL, str]]:
    """Loaded OpenBLAS libraries and their symbol prefix."""
    out = []
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({line.split()[-1] for line in fh if "openblas" in line.lower() and ".so" in line})
    except OSError:
        return out
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for pre in _PREFIXES:
            for suf in _SUFFIXES:
                if hasattr(lib, f"{pre}_set_num_threads{suf}") and hasattr(lib, f"{pre}_get_num_threads{suf}"):
                    out.append((lib, f"{pre}_%s_num_threads{suf}"))
                    break
            else:
                continue
            break
    return out


@contextmanager
def blas_threads(n: int = 1) -> Iterator[None]:
    """Run the block with ``n`` BLAS threads in every loaded OpenBLAS (no-op where none is found)."""
    import numpy  # noqa: F401  (load the libraries first)
    import scipy.linalg  # noqa: F401

    libs = _libraries()
    before = []
    for lib, pat in libs:
        before.append(int(getattr(lib, pat % "get")()))
        getattr(lib, pat % "set")(int(n))
    try:
        yield
    finally:
        for (lib, pat), k in zip(libs, before, strict=True):
            getattr(lib, pat % "set")(k)
