"""host.memory.return_free_heap: freed arrays that glibc kept in its heaps go back to the system."""

from __future__ import annotations

import ctypes.util
import sys

import numpy as np
import pytest

from thintact_sdk.host.memory import return_free_heap


def _private_mib() -> int:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("RssAnon")) // 1024


@pytest.mark.skipif(not sys.platform.startswith("linux") or "libc.so" not in str(ctypes.util.find_library("c")),
                    reason="malloc_trim is glibc's")
def test_freed_frames_held_in_the_heap_are_given_back():
    # a freed 30 MiB block raises glibc's mmap threshold: the 4 MiB arrays after it come from
    # the heap, and one array allocated last keeps the heap's top in use
    big = np.ones(30 << 20, np.uint8)
    del big
    arrays = [np.ones(4 << 20, np.uint8) for _ in range(100)]
    top = np.ones(1 << 20, np.uint8)
    held = _private_mib()
    del arrays
    assert return_free_heap() in (True, False)
    after = _private_mib()
    assert held - after >= 300, (held, after)
    assert top.sum() == 1 << 20  # still valid after the trim

