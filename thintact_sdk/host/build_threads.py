"""Independent pieces of a kernel build on the host's cores, one BLAS thread each.

The rotated + refracted kernel (:mod:`thintact_sdk.simulation.refracted`) is the slowest
build of the simulator (about 20 s CPU on a 128×160 device at 0.3°): two one-axis families
tabulated independently, then a few dozen independent groups of products compressed and
merged. Those pieces never wait on each other, so they are run on separate threads (numpy and
OpenBLAS release the GIL), with OpenBLAS held at one thread per piece: on a core shared with
another job one piece slows down and the join waits for it, so the build degrades to about
its serial time instead of the 2-6× a threaded product loses there
(:mod:`thintact_sdk.host.compute_threads`). ``THINTACT_BUILD_THREADS`` sets the number (1 runs
everything in the calling thread).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from thintact_sdk.errors import InvalidValueError
from thintact_sdk.host.blas import blas_threads
from thintact_sdk.host.compute_threads import usable_cores

ENV_BUILD_THREADS = "THINTACT_BUILD_THREADS"
MAX_BUILD_THREADS = 8

T = TypeVar("T")
R = TypeVar("R")

_worker = threading.local()


def build_threads(environ: dict[str, str] | None = None) -> int:
    """Threads a kernel build uses: ``THINTACT_BUILD_THREADS`` (1-8) if set, else the usable
    cores (at most :data:`MAX_BUILD_THREADS`).

    Raises
    ------
    InvalidValueError
        When the variable is not an integer from 1 to 8.
    """
    env = os.environ if environ is None else environ
    raw = env.get(ENV_BUILD_THREADS, "").strip()
    if not raw:
        return max(1, min(MAX_BUILD_THREADS, usable_cores()))
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if not 1 <= n <= MAX_BUILD_THREADS:
        raise InvalidValueError(f"{ENV_BUILD_THREADS}={raw!r}: must be an integer from 1 to "
                                f"{MAX_BUILD_THREADS}")
    return n


def thread_map(fn: Callable[[T], R], items: Sequence[T], threads: int | None = None) -> list[R]:
    """``[fn(item) for item in items]``, the items spread over ``threads`` threads
    (default :func:`build_threads`) with OpenBLAS at one thread; results in the items' order.
    An exception in any item is raised here. One thread, or one item, runs inline, and so does
    a map called from inside another map's item (no nested pools)."""
    n = min(len(items), build_threads() if threads is None else threads)
    if n <= 1 or getattr(_worker, "active", False):
        return [fn(item) for item in items]

    def run(item: T) -> R:
        _worker.active = True
        try:
            return fn(item)
        finally:
            _worker.active = False

    with blas_threads(1), ThreadPoolExecutor(max_workers=n, thread_name_prefix="kernel-build") as pool:
        return list(pool.map(run, items))


def per_channel_by_wavelength(wavelengths_nm: Sequence[float], channels: int,
                              build: Callable[[float], R], threads: int | None = None) -> list[R]:
    """``build(λ)`` once per distinct wavelength, the wavelengths side by side on ``threads``
    build threads (default :func:`build_threads`), listed per channel (channel ``c`` uses
    ``wavelengths_nm[min(c, len - 1)]``, as the profile's ``diffraction.wavelength_nm`` says);
    channels of one wavelength share the same result object. Side by side where every
    wavelength's kernel is bounded in size (rotated and refracted kernels refuse large
    devices); the plain diffraction kernel, which runs at the paper's size, passes
    ``threads=1`` to build them one after another."""
    lams = [float(wavelengths_nm[min(ch, len(wavelengths_nm) - 1)]) for ch in range(channels)]
    distinct = list(dict.fromkeys(lams))
    built = dict(zip(distinct, thread_map(build, distinct, threads), strict=True))
    return [built[lam] for lam in lams]
