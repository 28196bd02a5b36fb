"""Give the C heap's free pages back to the operating system (glibc's ``malloc_trim``).

numpy allocates array data with ``malloc``. glibc serves a large request by ``mmap`` (handed
back on ``free``) only above its mmap threshold, and it raises that threshold to the size of
each large block freed, up to 32 MiB on 64-bit hosts. After the first paper-size frame is
freed, frames and their temporaries (a 1024 × 1280 × 3 float32 frame is 15.7 MB) come from
the heaps instead, one per thread that allocated, and a freed block stays in the process's
resident memory until the heap above it is freed too. A long calibration whose threads
allocate and free such arrays for minutes ends up holding hundreds of MB of free heap
(measured in docs/calibration.md, issue 36).

:func:`return_free_heap` trims every heap (glibc 2.8 and later also release free pages in
the middle of a heap). It is cheap next to a calibration stage; it is no replacement for
holding less. Off glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys
import threading
from typing import Any

_lock = threading.Lock()
_trim: Any = None
_looked = False


def _malloc_trim() -> Any:
    """glibc's ``malloc_trim``, or None (another C library, or not Linux)."""
    global _trim, _looked
    with _lock:
        if not _looked:
            _looked = True
            if sys.platform.startswith("linux"):
                try:
                    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                    fn = libc.malloc_trim
                except (OSError, AttributeError):  # musl and others have no malloc_trim
                    fn = None
                if fn is not None:
                    fn.argtypes = [ctypes.c_size_t]
                    fn.restype = ctypes.c_int
                _trim = fn
        return _trim


def return_free_heap() -> bool:
    """Hand the free pages of every malloc heap back to the operating system.

    Returns
    -------
    bool
        True when glibc released memory; False when there was none to release, or the C
        library is not glibc (nothing is done then).
    """
    fn = _malloc_trim()
    return bool(fn(0)) if fn is not None else False
