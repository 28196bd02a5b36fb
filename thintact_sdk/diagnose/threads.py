"""Limiting numpy's OpenBLAS threads while the diagnosis runs.

The diagnosis multiplies many small matrices; on a busy machine OpenBLAS threads that
spin-wait for each other make that 10-30× slower than one thread (measured on 2 shared
cores: 2.7 s vs 0.1 s for one 12-frame simulation). numpy exposes no thread control, so
this calls the bundled OpenBLAS's own setter through ctypes when it is found, and does
nothing otherwise.
"""

from __future__ import annotations

import ctypes
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads")


def _openblas() -> ctypes.CDLL | None:
    import numpy  # noqa: F401 - makes sure numpy's OpenBLAS is loaded

    try:
        with open("/proc/self/maps", encoding="utf-8") as f:
            paths = sorted({ln.split()[-1] for ln in f if "openblas" in ln.lower() and "/" in ln})
    except OSError:
        return None
    for p in paths:
        try:
            return ctypes.CDLL(p)
        except OSError:
            continue
    return None


def _fn(lib: ctypes.CDLL, names: tuple[str, ...]) -> Any:
    for n in names:
        if hasattr(lib, n):
            return getattr(lib, n)
    return None


@contextmanager
def blas_threads(n: int | None) -> Iterator[None]:
    """Run the body with OpenBLAS limited to ``n`` threads (None: leave as is)."""
    lib = _openblas() if n else None
    setter = _fn(lib, _SETTERS) if lib is not None else None
    getter = _fn(lib, _GETTERS) if lib is not None else None
    if setter is None or getter is None or not n:
        yield
        return
    old = int(getter())
    setter(int(n))
    try:
        yield
    finally:
        setter(old)
