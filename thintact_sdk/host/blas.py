"""Limit the threads of the OpenBLAS libraries numpy and scipy loaded (no extra dependency).

Work made of many small matrix products (the GA's eigen-decompositions with N ≤ 512, the
diagnosis's repeated small simulations) gains little from threaded OpenBLAS and loses badly
on a busy machine, where threads spin-wait for each other: many times slower with 2
threads under load than with 1 (docs/benchmarks.md, history).
numpy exposes no thread control, so this calls each loaded OpenBLAS's own setter through
ctypes when it is found, and changes nothing otherwise.
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

_SET_NAMES = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
              "openblas_set_num_threads64_", "openblas_set_num_threads")
_GET_NAMES = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
              "openblas_get_num_threads64_", "openblas_get_num_threads")


_scanned: tuple[int, list[tuple[Any, Any]]] | None = None
_scan_lock = threading.Lock()


def _loaded_openblas() -> list[tuple[Any, Any]]:
    """(set, get) function pairs of every OpenBLAS mapped into this process (Linux).

    Reading ``/proc/self/maps`` costs milliseconds, too much for a hold taken once per frame
    (:meth:`thintact_sdk.device.sensor.Sensor.process`), so the scan is kept until a module is
    imported (the only way a new OpenBLAS gets mapped in)."""
    global _scanned
    import numpy  # noqa: F401 - make sure numpy's BLAS is loaded
    import scipy.linalg  # noqa: F401 - and scipy's

    modules = len(sys.modules)
    with _scan_lock:
        if _scanned is not None and _scanned[0] == modules:
            return _scanned[1]
    found = _scan_openblas()
    with _scan_lock:
        _scanned = (modules, found)
    return found


def _openblas_paths() -> list[str]:
    """Files of the OpenBLAS libraries mapped into this process, in address order (Linux)."""
    paths: list[str] = []
    try:
        # a mapped file's name need not be UTF-8 (a memory-mapped frame named b"\xff.npy")
        with open("/proc/self/maps", encoding="utf-8", errors="surrogateescape") as f:
            for line in f:
                path = line.split()[-1] if "/" in line else ""
                if "openblas" in path.lower() and path not in paths:
                    paths.append(path)
    except OSError:
        return []
    return paths


def _scan_openblas() -> list[tuple[Any, Any]]:
    """:func:`_loaded_openblas` without the cache."""
    found: list[tuple[str, tuple[Any, Any]]] = []
    for path in _openblas_paths():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(lib, n) for n in _SET_NAMES if hasattr(lib, n)), None)
        getter = next((getattr(lib, n) for n in _GET_NAMES if hasattr(lib, n)), None)
        if setter is not None and getter is not None:
            getter.restype = ctypes.c_int
            found.append((path, (setter, getter)))
    # numpy's own first: :func:`openblas_threads` reads the first, and another package's copy
    # (OpenCV ships one) can be mapped at a lower address and keep its default thread count
    found.sort(key=lambda item: _numpy_first(item[0]))
    return [pair for _, pair in found]


def _numpy_first(path: str) -> int:
    """Sort key of a library path: 0 for numpy's OpenBLAS, 1 for scipy's, 2 for any other."""
    import numpy
    import scipy

    path = os.path.realpath(path)  # the maps name files by their real paths; a venv may be a link
    for rank, package in enumerate((numpy, scipy)):
        root = os.path.dirname(os.path.realpath(str(package.__file__)))
        if path.startswith((root + os.sep, root + ".libs" + os.sep)):
            return rank
    return 2


@contextmanager
def blas_threads(n: int | None) -> Iterator[int]:
    """Run the block with every loaded OpenBLAS limited to ``n`` threads, then restore.

    ``n`` None or 0 leaves the threads as they are. Yields the number of libraries it
    controls (0: none found or nothing asked, nothing changed).
    """
    libs = _loaded_openblas() if n else []
    before = [int(get()) for _, get in libs]
    for setter, _ in libs:
        setter(ctypes.c_int(int(n or 0)))
    try:
        yield len(libs)
    finally:
        for (setter, _), old in zip(libs, before, strict=True):
            setter(ctypes.c_int(old))


def openblas_threads() -> int | None:
    """Threads of numpy's OpenBLAS (the one numpy's products run on; else the first OpenBLAS
    mapped into this process), or None when none is found."""
    libs = _loaded_openblas()
    return int(libs[0][1]()) if libs else None
