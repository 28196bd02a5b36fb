"""Sensor.stream as a pipeline: stages overlap, the decoder warms up outside the read
timeout, frames carry their age. Stages are slowed with sleeps (no CPU), so the figures
hold on a loaded machine."""

from __future__ import annotations

import time

import numpy as np
import pytest
from tac_fakes import SLOTS, BlockDecoder, block_profile, make_registry

import thintact_sdk
from thintact_sdk.device.sensor import Sensor
from thintact_sdk.formats.profiles import DecoderConfig
from thintact_sdk.frames import TactileFrame
from thintact_sdk.tactile import TactileSimulator, scene_level_lut

STAGE_S = 0.06


class SlowDecoder(BlockDecoder):
    """Block decoder taking ``STAGE_S`` per frame, and ``first_s`` extra on its first decode."""

    def __init__(self, first_s: float = 0.0) -> None:
        self.first_s = first_s
        self.calls = 0

    def decode(self, signal: np.ndarray) -> np.ndarray:
        self.calls += 1
        time.sleep(STAGE_S + (self.first_s if self.calls == 1 else 0.0))
        return super().decode(signal)


class _SlowStartPlugin:
    """A decoder whose construction takes 1.2 s (as backend selection on a new host)."""

    @thintact_sdk.hookimpl
    def thintact_decoders(self):
        def build(profile, settings):
            time.sleep(1.2)
            return SlowDecoder(first_s=0.8)

        return [thintact_sdk.Component("tac-slow-start", build, "test")]


@pytest.fixture(scope="module")
def profile():
    return block_profile()


@pytest.fixture(scope="module")
def lut(profile):
    return scene_level_lut(profile)


@pytest.fixture(autouse=True)
def _flat_scene(profile):
    SLOTS["tac-block"] = TactileSimulator.for_profile(profile).flat().scene
    yield
    SLOTS.clear()


def _slow_interpreter(sensor: Sensor) -> None:
    """Interpretation that takes ``STAGE_S`` and no CPU (so the test holds under load)."""

    def slow(image, timestamp_ns, frame_id):
        time.sleep(STAGE_S)
        empty = np.zeros((0, 2), np.float32)
        return TactileFrame(image, np.zeros(image.shape[:2], np.float32), empty, empty, False, 0.0,
                            timestamp_ns, frame_id)

    sensor.interpreter.interpret = slow  # type: ignore[method-assign]


def test_stream_overlaps_decode_and_interpretation(profile, lut) -> None:
    """Decode and interpretation take ≥ 60 ms each. One after the other, frames/s × the
    compute time per frame (bin + decode + interpret) cannot exceed 1; pipelined it is ~2."""
    with Sensor(profile, registry=make_registry(), lut=lut, decoder=SlowDecoder(),
                camera_settings={"fps": 100.0}) as s:
        _slow_interpreter(s)
        frames = []
        t0 = 0.0
        for frame in s.stream(max_frames=16, timeout_s=5.0):
            if not frames:
                t0 = time.perf_counter()
            frames.append(frame)
        fps = (len(frames) - 1) / (time.perf_counter() - t0)
    compute_s = float(np.mean([f.latency_ms for f in frames])) / 1e3
    assert fps * compute_s > 1.3, f"{fps:.1f} fps at {compute_s * 1e3:.0f} ms per frame: no overlap"
    ids = [f.frame_id for f in frames]
    assert ids == sorted(ids) and len(set(ids)) == len(ids)
    assert all(f.latency_ms is not None and f.latency_ms >= 2 * STAGE_S * 1e3 * 0.9 for f in frames)
    ages = [f.meta["age_ms"] for f in frames]
    assert list(s.stats.age_ms) == ages and min(ages) >= 2 * STAGE_S * 1e3 * 0.9
    assert s.stats.age_percentile_ms(50) <= s.stats.age_percentile_ms(99)


def test_decoder_warm_up_does_not_count_against_the_read_timeout(profile, lut) -> None:
    """Building the decoder (1.2 s) and its first decode (0.8 s extra) exceed the 0.5 s read
    timeout; the stream still delivers its first frame."""
    reg = make_registry()
    reg.register(_SlowStartPlugin(), "tac-slow-start")
    slow = profile.model_copy(update={"decoder": DecoderConfig(plugin="tac-slow-start")}, deep=True)
    with Sensor(slow, registry=reg, lut=lut, read_timeout_s=0.5, camera_settings={"fps": 50.0}) as s:
        frame = next(s.stream(max_frames=1))
        assert frame.frame_id >= 1
        assert s.stats.warm_up_s >= 2.0
        assert isinstance(s.decoder, SlowDecoder) and s.decoder.calls >= 2


def test_warm_up_does_not_touch_the_reference(profile, lut) -> None:
    with Sensor(profile, registry=make_registry(), lut=lut, reference_frames=2) as s:
        assert s.warm_up() >= 0.0
        assert s.interpreter._ref_count == 0


def test_bench_tactile_reports_streamed_fps_and_latency_percentiles(profile, lut) -> None:
    from tac_fakes import BlockCamera

    from thintact_sdk.apps.benchmarks.tactile_accuracy import _streamed_fps

    cam = BlockCamera(profile, {})
    cam.open()
    raws = [cam.read() for _ in range(3)]
    sensor = Sensor(profile, registry=make_registry(), lut=lut, decoder=BlockDecoder())
    stream = _streamed_fps(profile, raws, sensor, frames=4, budget_s=2.0)
    assert stream["fps"] > 0 and stream["processed"] >= 2
    assert 0 < stream["latency_p50_ms"] <= stream["latency_p99_ms"]
    assert stream["waited_ms_max"] >= 0 and stream["warm_up_s"] >= 0


class _AlternatingDecoder(BlockDecoder):
    """Every other decode is slow (150 ms against 10 ms): with two workers, frames finish out
    of order."""

    def __init__(self) -> None:
        self.calls = 0

    def decode(self, signal: np.ndarray) -> np.ndarray:
        self.calls += 1
        time.sleep(0.15 if self.calls % 2 else 0.01)
        return super().decode(signal)


def _fps(profile, lut, decoder, monkeypatch, workers: int, frames: int = 12) -> tuple[float, Sensor]:
    monkeypatch.setenv("THINTACT_DECODE_WORKERS", str(workers))
    with Sensor(profile, registry=make_registry(), lut=lut, decoder=decoder,
                camera_settings={"fps": 200.0}) as s:
        got = []
        t0 = 0.0
        for frame in s.stream(max_frames=frames, timeout_s=5.0):
            if not got:
                t0 = time.perf_counter()
            got.append(frame.frame_id)
        fps = (len(got) - 1) / (time.perf_counter() - t0)
    assert got == sorted(got) and len(set(got)) == len(got), got
    return fps, s


def test_two_decode_workers_double_the_rate_of_a_decode_bound_stream(profile, lut, monkeypatch) -> None:
    """Decode is the slow stage (60 ms, no CPU): two workers decode consecutive frames at once,
    so the stream runs at about twice the one-worker rate (compared in the same run)."""
    one, s1 = _fps(profile, lut, SlowDecoder(), monkeypatch, 1)
    two, s2 = _fps(profile, lut, SlowDecoder(), monkeypatch, 2)
    assert s1.stats.decode_workers == 1 and s2.stats.decode_workers == 2
    assert two > 1.5 * one, f"one worker {one:.1f} fps, two {two:.1f} fps"


def test_a_frame_finished_after_a_newer_one_is_skipped_not_delivered_late(profile, lut, monkeypatch) -> None:
    fps, s = _fps(profile, lut, _AlternatingDecoder(), monkeypatch, 2, frames=10)
    assert fps > 0 and s.stats.skipped > 0  # the slow ones were overtaken and dropped


def test_streaming_holds_kernel_threads_at_one_and_restores_them(profile, lut, monkeypatch) -> None:
    import torch

    from thintact_sdk.host.blas import openblas_threads
    from thintact_sdk.host.compute_threads import kernel_threads_held

    monkeypatch.setenv("THINTACT_DECODE_WORKERS", "2")
    monkeypatch.setattr("thintact_sdk.device.sensor.usable_cores", lambda: 8)  # the warm-up keeps the threads
    torch_before, blas_before = torch.get_num_threads(), openblas_threads()
    seen: list[tuple[int, int | None, int]] = []

    class Probe(BlockDecoder):
        def decode(self, signal: np.ndarray) -> np.ndarray:
            seen.append((torch.get_num_threads(), openblas_threads(), kernel_threads_held()))
            return super().decode(signal)

    with Sensor(profile, registry=make_registry(), lut=lut, decoder=Probe()) as s:
        list(s.stream(max_frames=3, timeout_s=5.0))
    during = seen[2:]  # the first two decodes are the warm-up, before the workers start
    assert [held for _, _, held in seen[:2]] == [0, 0]
    assert during and all(t == 1 and held == 1 for t, _, held in during)
    if blas_before is not None:
        assert all(b == 1 for _, b, _ in during)
    assert (torch.get_num_threads(), openblas_threads(), kernel_threads_held()) == (torch_before, blas_before, 0)


@pytest.mark.parametrize(("cores", "held"), [(2, 1), (8, 0)])
def test_a_two_core_host_streams_one_worker_on_one_kernel_thread(profile, lut, monkeypatch, cores, held) -> None:
    """On 2 cores the stream's other stages share the cores with the decode, so even one
    worker decodes on one kernel thread, timed that way at warm-up; restored after. A larger
    host keeps the threads for a single worker."""
    import torch

    from thintact_sdk.host.blas import openblas_threads
    from thintact_sdk.host.compute_threads import kernel_threads_held

    monkeypatch.setenv("THINTACT_DECODE_WORKERS", "1")
    monkeypatch.setattr("thintact_sdk.device.sensor.usable_cores", lambda: cores)
    before = (torch.get_num_threads(), openblas_threads(), 0)
    seen: list[int] = []

    class Probe(BlockDecoder):
        def decode(self, signal: np.ndarray) -> np.ndarray:
            seen.append(kernel_threads_held())
            return super().decode(signal)

    with Sensor(profile, registry=make_registry(), lut=lut, decoder=Probe()) as s:
        list(s.stream(max_frames=3, timeout_s=5.0))
        assert s.stats.decode_workers == 1
    # warm-up (2) and streamed frames alike; the warm-up's decodes sit in the frame's own hold
    # inside the stream's (counted, so 2 holders there)
    assert len(seen) >= 5 and {min(h, 1) for h in seen} == {held}
    assert (torch.get_num_threads(), openblas_threads(), kernel_threads_held()) == before


def test_workers_are_chosen_from_the_decode_timed_at_warm_up(profile, lut, monkeypatch) -> None:
    """A 60 ms decode does not fit in a 100 fps camera's period: one worker per usable core.
    A fast decode at 10 fps does: one worker (the lowest latency)."""
    from thintact_sdk.host.compute_threads import suggested_decode_workers

    monkeypatch.delenv("THINTACT_DECODE_WORKERS", raising=False)
    for decoder, fps, want in ((SlowDecoder(), 100.0, suggested_decode_workers()), (BlockDecoder(), 10.0, 1)):
        with Sensor(profile, registry=make_registry(), lut=lut, decoder=decoder,
                    camera_settings={"fps": fps}) as s:
            next(s.stream(max_frames=1, timeout_s=5.0))
            assert s.decode_ms is not None
            assert s.stats.decode_workers == want, (fps, s.decode_ms)


@pytest.mark.parametrize(("cores", "held"), [(2, 1), (8, 0)])
def test_a_single_frame_decodes_on_one_kernel_thread_on_two_cores(profile, lut, monkeypatch, cores, held) -> None:
    """``read()`` / ``process()`` on 2 cores: one kernel thread, as in a stream (with another
    job on the second core, two threads made the paper decode 10× slower); restored after
    every frame. A larger host keeps the library's threads."""
    import torch

    from thintact_sdk.host.blas import openblas_threads
    from thintact_sdk.host.compute_threads import kernel_threads_held

    monkeypatch.setattr("thintact_sdk.device.sensor.usable_cores", lambda: cores)
    before = (torch.get_num_threads(), openblas_threads(), 0)
    seen: list[tuple[int, int | None]] = []

    class Probe(BlockDecoder):
        def decode(self, signal: np.ndarray) -> np.ndarray:
            seen.append((kernel_threads_held(), openblas_threads()))
            return super().decode(signal)

    with Sensor(profile, registry=make_registry(), lut=lut, decoder=Probe()) as s:
        for _ in range(3):
            s.read()
            assert (torch.get_num_threads(), openblas_threads(), kernel_threads_held()) == before
    assert len(seen) == 3 and {h for h, _ in seen} == {held}
    if held and before[1] is not None:
        assert {b for _, b in seen} == {1}
