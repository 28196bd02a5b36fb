"""compute_threads: how many decode workers a stream uses, and the counted one-thread hold."""

from __future__ import annotations

import threading

import pytest

from thintact_sdk.errors import InvalidValueError, ThinTactError
from thintact_sdk.host.blas import openblas_threads
from thintact_sdk.host.compute_threads import (
    MAX_DECODE_WORKERS,
    decode_workers,
    kernel_threads_held,
    single_threaded_kernels,
    suggested_decode_workers,
    usable_cores,
)


def test_decode_workers_are_chosen_from_the_measured_decode_and_the_camera_rate() -> None:
    many = suggested_decode_workers()
    assert many == max(1, min(usable_cores(), MAX_DECODE_WORKERS))
    assert decode_workers(None, 30.0, environ={}) == 1  # nothing measured
    assert decode_workers(10.0, 30.0, environ={}) == 1  # fits in 33 ms: lowest latency
    assert decode_workers(45.0, 30.0, environ={}) == many  # does not: keep up with the camera
    assert decode_workers(10.0, None, environ={}) == many  # free-running camera
    assert decode_workers(45.0, 30.0, environ={"THINTACT_DECODE_WORKERS": "1"}) == 1
    assert decode_workers(1.0, 30.0, environ={"THINTACT_DECODE_WORKERS": " 3 "}) == 3


@pytest.mark.parametrize("bad", ["0", "-1", "two", "1.5", "17"])
def test_a_bad_worker_count_is_a_clear_error(bad: str) -> None:
    with pytest.raises(InvalidValueError, match="THINTACT_DECODE_WORKERS") as err:
        decode_workers(50.0, 30.0, environ={"THINTACT_DECODE_WORKERS": bad})
    assert isinstance(err.value, ThinTactError)


def test_nested_holds_from_two_threads_restore_the_first_settings() -> None:
    import torch

    from thintact_sdk.host.compute_threads import prepare_worker_thread

    torch_before, blas_before = torch.get_num_threads(), openblas_threads()
    inner_started, release = threading.Event(), threading.Event()
    worker_saw: list[int] = []

    def other_sensor() -> None:
        with single_threaded_kernels():
            prepare_worker_thread()
            worker_saw.append(torch.get_num_threads())
            inner_started.set()
            release.wait(5.0)

    with single_threaded_kernels():
        t = threading.Thread(target=other_sensor)
        t.start()
        assert inner_started.wait(5.0)
        assert kernel_threads_held() == 2
        assert blas_before is None or openblas_threads() == 1
        assert torch.get_num_threads() == torch_before  # the caller's own threads are untouched
    # the first holder left while the second still holds: nothing restored yet
    assert kernel_threads_held() == 1 and (blas_before is None or openblas_threads() == 1)
    release.set()
    t.join(5.0)
    assert worker_saw == [1] and kernel_threads_held() == 0
    assert (torch.get_num_threads(), openblas_threads()) == (torch_before, blas_before)

    def fresh() -> None:
        worker_saw.append(torch.get_num_threads())

    t = threading.Thread(target=fresh)
    t.start()
    t.join(5.0)
    assert worker_saw[-1] == torch_before  # new threads start from the restored value


def test_the_threads_reported_are_numpys_even_with_opencvs_openblas_mapped_first(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """OpenCV ships its own OpenBLAS, which can be mapped at a lower address than numpy's and
    keeps its default threads when a hold began before it was loaded: the threads reported (the
    backend cache's key) must still be the ones numpy's products run on (a calibration once
    re-measured every backend mid-run because the count it reported flipped to OpenCV's)."""
    import ctypes

    import cv2  # noqa: F401 - maps OpenCV's OpenBLAS

    from thintact_sdk.host import blas

    paths = blas._openblas_paths()
    numpy_path = [q for q in paths if blas._numpy_first(q) == 0]
    others = [q for q in paths if blas._numpy_first(q) == 2]
    if not numpy_path or not others:
        pytest.skip("numpy's and another package's OpenBLAS are not both mapped here")
    monkeypatch.setattr(blas, "_openblas_paths", lambda: others + [q for q in paths if q not in others])
    libs = blas._scan_openblas()
    before = [int(get()) for _, get in libs]
    try:
        for setter, _ in libs:
            setter(ctypes.c_int(3))
        numpy_lib = ctypes.CDLL(numpy_path[0])
        setter = next(getattr(numpy_lib, n) for n in ("scipy_openblas_set_num_threads64_", "openblas_set_num_threads64_",
                                                      "openblas_set_num_threads") if hasattr(numpy_lib, n))
        setter(ctypes.c_int(1))
        assert int(libs[0][1]()) == 1  # numpy's is read first
    finally:
        for (setter, _), old in zip(libs, before, strict=True):
            setter(ctypes.c_int(old))


def test_torch_loaded_after_the_hold_began_is_held_at_one_thread_and_put_back() -> None:
    """A fresh process opens a sensor before anything imports torch: the hold begins, then the
    decoder's backend selection loads torch. Its products must run (and be measured) on one
    thread as in every later build of the process, and the hold's end puts back torch's
    count (before, the first build measured on torch's default threads and chose apart)."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from thintact_sdk.host.compute_threads import prepare_worker_thread, single_threaded_kernels\n"
        "assert 'torch' not in sys.modules\n"
        "with single_threaded_kernels():\n"
        "    prepare_worker_thread()\n"  # torch not loaded yet: nothing to hold
        "    import torch\n"
        "    torch.set_num_threads(2)\n"  # the default on a 2-core host, whatever the env says
        "    prepare_worker_thread()\n"
        "    inside = torch.get_num_threads()\n"
        "print(inside, torch.get_num_threads())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["1", "2"]


def test_a_torch_another_thread_is_still_importing_counts_as_not_loaded(monkeypatch) -> None:
    """Two sensors viewed at once: one's first frame imports torch while the other's frame
    takes the hold. The other saw the partly built module in ``sys.modules`` and failed with
    ``AttributeError: partially initialized module 'torch'`` (its viewer never showed a
    frame). A module still initialising is left alone; a complete one is used."""
    import importlib.machinery
    import sys
    import types

    import torch

    from thintact_sdk.host.compute_threads import loaded_torch, prepare_worker_thread
    from thintact_sdk.host.machine import kernel_threads_now

    partial = types.ModuleType("torch")
    partial.__spec__ = importlib.machinery.ModuleSpec("torch", None)
    partial.__spec__._initializing = True  # what the import system sets while it runs
    monkeypatch.setitem(sys.modules, "torch", partial)
    assert loaded_torch() is None
    with single_threaded_kernels():
        prepare_worker_thread()
        assert kernel_threads_now().endswith("torch -")
    assert kernel_threads_held() == 0
    partial.__spec__._initializing = False  # finished, but without the thread setters
    assert loaded_torch() is None
    monkeypatch.setitem(sys.modules, "torch", torch)
    assert loaded_torch() is torch
    before = torch.get_num_threads()
    done = threading.Event()
    seen: list[int] = []

    def worker() -> None:
        with single_threaded_kernels():
            prepare_worker_thread()
            seen.append(torch.get_num_threads())
        done.set()

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join(30)
    assert done.is_set() and seen == [1] and torch.get_num_threads() == before
