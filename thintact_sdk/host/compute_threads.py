"""How the stream pipeline spends the host's cores: optionally several decode workers, one
kernel thread each.

A decode split over two cores inside one product (OpenBLAS or torch intra-op threads) waits
on its slowest thread at every product: when anything else runs on the second core it slows
several-fold, where a decode on one kernel thread does not. Decoding consecutive frames on
separate workers, one kernel thread each, avoids those waits.

In the whole stream pipeline two workers pay where the decode is the bottleneck (more tactile
frames/s, quiet or with a core busy); where one decode fits in a camera period both keep up
with the camera and one worker has the lower latency (``tools/bench_stream_workers.py``
measures both; the figures are in docs/benchmarks.md). So the choice is measured:
:func:`decode_workers` takes one worker when a decode (timed at warm-up) fits in the camera's
frame period, else one per usable core; ``THINTACT_DECODE_WORKERS`` overrides.

:func:`decode_workers` says how many workers a stream uses, and
:func:`single_threaded_kernels` holds OpenBLAS at one thread while any stream with several
workers runs (process-wide, counted, the previous setting restored by the last), each worker
setting torch to one thread in its own thread (:func:`prepare_worker_thread`).
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from types import ModuleType

from thintact_sdk.errors import InvalidValueError
from thintact_sdk.host.blas import blas_threads

MAX_DECODE_WORKERS = 4
ENV_DECODE_WORKERS = "THINTACT_DECODE_WORKERS"

PIPELINE_SHARES_CORES_UP_TO = 2
"""On a host with at most this many usable cores a stream holds the kernels at one thread
even with one decode worker. Its other stages (Bayer binning, tactile interpretation, a
third of the paper device's frame period or more) run while it decodes, so a product split
over both cores waits for the core they hold at every product: one worker on two kernel
threads streams several times fewer frames/s than on one (tools/bench_stream_workers.py;
docs/benchmarks.md). On larger hosts a single worker keeps the library's threads (the other
stages take a smaller share of the cores; not measured here)."""

_lock = threading.Lock()
_holders = 0
_restore: ExitStack | None = None
_torch_threads_before: int | None = None


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def decode_workers(decode_ms: float | None = None, camera_fps: float | None = None,
                   environ: dict[str, str] | None = None) -> int:
    """Decode workers for a stream.

    ``THINTACT_DECODE_WORKERS`` if set (1-16). Otherwise measured: one worker (the lowest
    latency) when one decode, measured on this host (``decode_ms``), fits in the camera's
    frame period; :func:`suggested_decode_workers` when it does not, or when the camera gives
    no frame rate, so the stream keeps up with the camera instead of dropping frames. One
    when nothing was measured.

    Raises
    ------
    InvalidValueError
        When the environment variable is not a whole number from 1 to 16.
    """
    env = os.environ if environ is None else environ
    text = env.get(ENV_DECODE_WORKERS, "").strip()
    if text:
        if not text.isdigit() or not 1 <= int(text) <= 16:
            raise InvalidValueError(f"{ENV_DECODE_WORKERS}={text!r}: expected a whole number from 1 to 16")
        return int(text)
    if decode_ms is None:
        return 1
    if camera_fps and camera_fps > 0 and decode_ms <= 1e3 / camera_fps:
        return 1
    return suggested_decode_workers()


def suggested_decode_workers() -> int:
    """The usable cores, at most :data:`MAX_DECODE_WORKERS`: what to try with
    ``THINTACT_DECODE_WORKERS`` (and measure) on a many-core host."""
    return max(1, min(usable_cores(), MAX_DECODE_WORKERS))


def loaded_torch() -> ModuleType | None:
    """torch if this process has finished importing it, else None (never imports it).

    While one thread imports torch (a sensor's backend selection does, on its first frame)
    the module is already in ``sys.modules``, partly built: another sensor's thread that
    read its thread count then failed with ``AttributeError: partially initialized module
    'torch'`` and its viewer never showed a frame. Such a module counts as not loaded: the
    thread importing it makes the call again once it is (:func:`prepare_worker_thread`)."""
    torch = sys.modules.get("torch")
    if torch is None or getattr(getattr(torch, "__spec__", None), "_initializing", False):
        return None
    if not (hasattr(torch, "get_num_threads") and hasattr(torch, "set_num_threads")):
        return None
    return torch


def prepare_worker_thread() -> None:
    """Call first in a decode worker thread while :func:`single_threaded_kernels` is held.

    torch's CPU thread count is per calling thread (OpenMP) once a thread has set it, and
    the value new threads start from: each worker sets its own to one, the caller's threads
    keep theirs, and the last hold to end puts back the value new threads start from. Does
    nothing while torch is not loaded (torch is never imported here); call it again once
    something may have loaded it (a decoder's backend selection does, before it measures):
    where torch was loaded after the hold began, the count it had then is what the hold puts
    back. Without that second call a decoder built in a fresh process measured its backends
    on torch's default threads and every later one on one thread, so the two chose apart.
    """
    global _torch_threads_before
    torch = loaded_torch()
    if torch is None:
        return
    with _lock:
        if _holders == 0:
            return
        if _torch_threads_before is None:  # loaded after the hold began
            _torch_threads_before = int(torch.get_num_threads())
    torch.set_num_threads(1)


@contextmanager
def single_threaded_kernels() -> Iterator[None]:
    """Hold OpenBLAS (process-wide) at one thread while the block runs, and let decode workers
    (:func:`prepare_worker_thread`) set torch to one thread in their own threads.

    Re-entrant across threads and sensors: the first holder saves the settings and the last
    one out restores them, so two sensors streaming at once never undo each other.
    """
    global _holders, _restore, _torch_threads_before
    with _lock:
        if _holders == 0:
            stack = ExitStack()
            stack.enter_context(blas_threads(1))
            torch = loaded_torch()
            _torch_threads_before = int(torch.get_num_threads()) if torch is not None else None
            _restore = stack
        _holders += 1
    try:
        yield
    finally:
        with _lock:
            _holders -= 1
            if _holders == 0:
                if _restore is not None:
                    _restore.close()
                torch = loaded_torch()
                if torch is not None and _torch_threads_before is not None:
                    torch.set_num_threads(_torch_threads_before)
                _restore = None
                _torch_threads_before = None


def kernel_threads_held() -> int:
    """How many streams hold :func:`single_threaded_kernels` now (for tests and ``doctor``)."""
    with _lock:
        return _holders
