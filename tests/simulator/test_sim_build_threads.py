"""Kernel builds split over threads (``thintact_sdk.host.build_threads``): the setting, the
map, and the rotated + refracted kernel built in round-robin groups equal to the serial one."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from tests.simulator.sim_helpers import rel_rms, tiny_profile
from thintact_sdk.errors import InvalidValueError
from thintact_sdk.host.build_threads import ENV_BUILD_THREADS, build_threads, thread_map
from thintact_sdk.simulation import refracted as sim_refracted
from thintact_sdk.simulation.simulator import Simulator, clear_kernel_cache


def test_build_threads_setting():
    assert build_threads({ENV_BUILD_THREADS: "3"}) == 3
    assert build_threads({}) >= 1
    for bad in ("0", "9", "two"):
        with pytest.raises(InvalidValueError, match=ENV_BUILD_THREADS):
            build_threads({ENV_BUILD_THREADS: bad})


def test_thread_map_keeps_order_runs_in_threads_and_raises():
    names: set[str] = set()
    barrier = threading.Barrier(2, timeout=10)

    def work(i: int) -> int:
        names.add(threading.current_thread().name)
        if i < 2:
            barrier.wait()  # both first items run at once, or this times out
        return i * i

    assert thread_map(work, list(range(6)), threads=2) == [0, 1, 4, 9, 16, 25]
    assert len(names) == 2
    assert thread_map(work, [5], threads=2) == [25]

    def fail(i: int) -> int:
        if i == 3:
            raise ValueError("item 3")
        return i

    with pytest.raises(ValueError, match="item 3"):
        thread_map(fail, list(range(5)), threads=2)


ROT_REFR = {"mask_misalignment": {"angle_deg": 2.0, "dx_um": -4.0, "dy_um": 2.0},
            "refraction": {"n_scene_side": 1.4}}
DEVICE = dict(rows=8, cols=10, pitch_um=20.0, scene_rows=4, scene_cols=5, scene_pitch_um=60.0,
              feature_um=20.0, k=40, z_mm=1.0, d_mm=0.3)


def _frames(monkeypatch: pytest.MonkeyPatch, threads: str, one_shot: int) -> np.ndarray:
    monkeypatch.setenv(ENV_BUILD_THREADS, threads)
    monkeypatch.setattr(sim_refracted, "ONE_SHOT_TERMS", one_shot)
    monkeypatch.setattr(sim_refracted, "MERGE_TERMS", 40)
    clear_kernel_cache()
    x = np.random.default_rng(5).random((2, 4, 5, 3))
    return Simulator(tiny_profile(ROT_REFR, **DEVICE)).forward_batch(x)


def test_grouped_rotated_refracted_build_equals_the_serial_one(monkeypatch):
    """The large-angle branch (one x basis matrix at a time, merged) on a small device: two
    round-robin groups on two threads give the one-group result, and both the one-shot
    compression, within the compression's own tolerance."""
    one_shot = _frames(monkeypatch, "1", 10**9)
    serial = _frames(monkeypatch, "1", 0)
    grouped = _frames(monkeypatch, "2", 0)
    clear_kernel_cache()
    assert rel_rms(grouped, serial) < 1e-6
    assert rel_rms(serial, one_shot) < 2e-5
    assert rel_rms(grouped, one_shot) < 2e-5


def test_thread_map_inside_an_item_runs_inline():
    def inner(i: int) -> str:
        return threading.current_thread().name

    def outer(i: int) -> set[str]:
        return set(thread_map(inner, [0, 1, 2], threads=2)) | {threading.current_thread().name}

    for names in thread_map(outer, [0, 1], threads=2):
        assert len(names) == 1  # the nested map ran in the item's own thread
