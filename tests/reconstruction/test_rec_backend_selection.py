"""Backend selection: measured on this host, never a trap, cached per host and operator."""

from __future__ import annotations

import time
import warnings
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from thintact_sdk.device.registry import get_registry
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.host.machine import (
    HostCapabilities,
    cpu_flags,
    has_native_bf16,
    host_capabilities,
)
from thintact_sdk.reconstruction.decoders import ArrayBackend, FlatCamDecoder
from thintact_sdk.reconstruction.decoders.backend_cache import BackendCache, cache_dir
from thintact_sdk.reconstruction.decoders.backend_candidates import (
    BackendSpec,
    candidate_specs,
    parse_preference,
)
from thintact_sdk.reconstruction.decoders.backend_selection import (
    BackendPreferenceWarning,
    decide,
    make_probes,
    select_backend,
)
from thintact_sdk.reconstruction.synthetic_matrices import frequency_split_matrices

SENSOR, SCENE, BLOCK = (64, 72), (20, 24), (8, 9)
HOST = HostCapabilities("Test CPU", 2, "AVX2", False, "openblas (2 threads)", "2.13.0+cpu, 2 threads", (),
                        ("avx2", "fma"))


class SleepyBackend(ArrayBackend):
    """numpy float32 that sleeps ``delay_s`` per frame (a backend forced to be slow)."""

    def __init__(self, delay_s: float) -> None:
        super().__init__("numpy", "float32")
        self.delay_s = delay_s

    def channels_first(self, image: np.ndarray, gemm: bool = False) -> Any:
        time.sleep(self.delay_s)
        return super().channels_first(image, gemm)


class NoisyBackend(ArrayBackend):
    """numpy float32 whose output carries an error (fast but inaccurate)."""

    def channels_last(self, a: Any) -> np.ndarray:
        out = super().channels_last(a)
        return out + np.random.default_rng(0).normal(0, 0.05, out.shape).astype(np.float32)


class FakeSpec(BackendSpec):
    def __init__(self, name: str, factory: Any) -> None:
        super().__init__("numpy")
        object.__setattr__(self, "_name", name)
        object.__setattr__(self, "_factory", factory)

    @property
    def key(self) -> str:
        return str(self._name)  # type: ignore[attr-defined]

    def make(self) -> ArrayBackend:
        return self._factory()  # type: ignore[attr-defined, no-any-return]


@pytest.fixture(scope="module")
def operator():
    sm, _ = frequency_split_matrices(SENSOR, SCENE, BLOCK, seed=1)
    return sm, make_probes(sm, load_profile("virtual-mini").noise)


def _select(operator, specs, tmp_path, preferred=None, calls=None):
    sm, probes = operator

    def build(xp):
        if calls is not None:
            calls.append(getattr(xp, "name", "?"))
        return FlatCamDecoder(sm, 1e-2, xp)

    return select_backend(build, lambda: probes, specs, "test-host|flatcam|small", preferred, "test",
                          cache=BackendCache(tmp_path / "backends.json"))


def test_a_backend_forced_to_be_slow_is_not_chosen_even_when_preferred(operator, tmp_path) -> None:
    fast = BackendSpec("numpy")
    slow = FakeSpec("numpy-sleepy", lambda: SleepyBackend(0.03))
    with pytest.warns(BackendPreferenceWarning, match="numpy-sleepy from test not used.*slower"):
        decoder, choice = _select(operator, [fast, slow], tmp_path, preferred=slow)
    assert choice.chosen == "numpy-float32" and not isinstance(decoder.xp, SleepyBackend)
    assert choice.measured_ms["numpy-sleepy"] > 30.0 > choice.measured_ms["numpy-float32"]


def test_a_fast_but_inaccurate_backend_is_rejected(operator, tmp_path) -> None:
    slowish = FakeSpec("numpy-float32", lambda: SleepyBackend(0.005))
    noisy = FakeSpec("numpy-noisy", lambda: NoisyBackend("numpy", "float32"))
    _, choice = _select(operator, [slowish, noisy], tmp_path)
    assert choice.measured_ms["numpy-noisy"] < choice.measured_ms["numpy-float32"]
    assert choice.psnr_cost_db["numpy-noisy"] > 0.1 >= choice.psnr_cost_db["numpy-float32"]
    assert choice.chosen == "numpy-float32"


def test_second_open_is_a_cache_hit_that_measures_nothing(operator, tmp_path) -> None:
    calls: list[str] = []
    specs = [BackendSpec("numpy"), BackendSpec("torch")]
    _, first = _select(operator, specs, tmp_path, calls=calls)
    assert not first.from_cache and len(calls) == 3  # float64 reference + two candidates
    calls.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        decoder, second = _select(operator, specs, tmp_path, calls=calls)
    assert second.from_cache and calls == [decoder.xp.name]  # only the decoder itself is built
    assert second.measured_ms == first.measured_ms and second.chosen == first.chosen


def test_a_cached_backend_that_is_no_candidate_now_is_never_chosen(operator, tmp_path) -> None:
    """A cache written when a (fast) backend was a candidate must not let that backend be
    chosen once it is not one: found on an AMX host, where the cache held torch-bfloat16 and
    a later selection without native bfloat16 still chose among the cached timings."""
    fast = FakeSpec("numpy-fast", lambda: ArrayBackend("numpy", "float32"))
    plain = BackendSpec("numpy")
    _select(operator, [plain, fast], tmp_path)
    cache = BackendCache(tmp_path / "backends.json")
    record = cache.get("test-host|flatcam|small")
    assert record is not None
    record["measured_ms"]["numpy-fast"] = 1e-6  # the no-longer-candidate looks unbeatable
    cache.put("test-host|flatcam|small", record)
    with pytest.warns(BackendPreferenceWarning, match="numpy-fast from test not used"):
        _, choice = _select(operator, [plain], tmp_path, preferred=fast)
    assert choice.from_cache and choice.chosen == "numpy-float32"
    assert "numpy-fast" not in choice.measured_ms


def test_preference_is_honoured_within_20_percent_only() -> None:
    ms, cost = {"numpy-float32": 10.0, "torch-float32": 11.5}, {"numpy-float32": 0.0, "torch-float32": 0.0}
    assert decide(ms, cost, "torch-float32") == ("torch-float32", None)
    ms["torch-float32"] = 12.5
    chosen, note = decide(ms, cost, "torch-float32", preferred_from="THINTACT_BACKEND")
    assert chosen == "numpy-float32" and note is not None and "25% slower" in note
    chosen, note = decide(ms, cost, "torch-bfloat16", unavailable={"torch-bfloat16": "emulated"})
    assert chosen == "numpy-float32" and note is not None and "emulated" in note
    chosen, note = decide(ms, {"numpy-float32": 0.5, "torch-float32": 0.3})
    assert chosen == "torch-float32" and note is not None and "most accurate" in note
    with pytest.raises(ValueError, match="no backend"):
        decide({}, {})


def test_bfloat16_is_a_candidate_only_with_native_support() -> None:
    assert not has_native_bf16({"avx2", "fma", "f16c"}, "AVX2")
    assert has_native_bf16({"avx512f", "avx512_bf16"}) and has_native_bf16({"amx_bf16"})
    assert has_native_bf16({"asimd", "bf16"}) and has_native_bf16(set(), "AMX")
    assert cpu_flags("processor: 0\nflags\t\t: fpu avx2 fma\n") == {"fpu", "avx2", "fma"}
    keys = [s.key for s in candidate_specs(HOST, torch_available=True)]
    assert keys == ["numpy-float32", "torch-float32"]
    native = replace(HOST, native_bf16=True, gpus=("cuda:0 Test GPU",))
    assert [s.key for s in candidate_specs(native, torch_available=True)] == [
        "numpy-float32", "torch-float32", "torch-bfloat16", "cuda-float32"]
    assert [s.key for s in candidate_specs(native, torch_available=False)] == ["numpy-float32"]
    if not host_capabilities().native_bf16:  # this host: AVX2 only
        assert "torch-bfloat16" not in [s.key for s in candidate_specs(host_capabilities())]


def test_preference_names() -> None:
    assert parse_preference("torch").key == "torch-float32"
    assert parse_preference("CUDA").key == "cuda-float32"
    assert parse_preference("torch-bfloat16").gemm_dtype == "bfloat16"
    with pytest.raises(ValueError, match="expected numpy"):
        parse_preference("tpu")


def test_a_bfloat16_profile_setting_decodes_in_float32_without_native_support(monkeypatch) -> None:
    import thintact_sdk.reconstruction.decoders.components as thintact_decoders

    monkeypatch.setattr(thintact_decoders, "host_capabilities",
                        lambda: replace(host_capabilities(), native_bf16=False))
    profile = load_profile("virtual-mini")
    with pytest.warns(BackendPreferenceWarning, match="torch-bfloat16 from decoder.settings not used.*emulated"):
        dec = get_registry().create("decoder", "thintact-noniterative", profile,
                                    {"backend": "torch", "gemm_dtype": "bfloat16"})
    assert dec.backend_choice.chosen in dec.backend_choice.measured_ms
    assert "bfloat16" not in dec.backend_choice.chosen and "torch-bfloat16" not in dec.backend_choice.measured_ms
    monkeypatch.setenv("THINTACT_BACKEND", "numpy-bfloat16")
    from thintact_sdk.errors import CalibrationError

    with pytest.raises(CalibrationError, match="THINTACT_BACKEND"):
        get_registry().create("decoder", "thintact-noniterative", profile, {})


def test_shipped_profiles_name_no_host_specific_backend() -> None:
    for name in ("thintact-paper", "virtual-finger", "virtual-mini"):
        cfg = load_profile(name).decoder
        assert cfg is not None
        assert not {"backend", "gemm_dtype", "device"} & set(cfg.settings), name


def test_cache_lives_in_the_user_cache_dir(monkeypatch, tmp_path) -> None:
    monkeypatch.delenv("THINTACT_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_dir() == tmp_path / "thintact"
    monkeypatch.setenv("THINTACT_CACHE_DIR", str(tmp_path / "x"))
    assert BackendCache().path == tmp_path / "x" / "decoder-backends.json"


def test_the_selection_is_cached_per_kernel_thread_count(monkeypatch, tmp_path) -> None:
    """A Sensor on a 2-core host decodes on one kernel thread and selects its backend there;
    `thintact bench reconstruct` measures on the library's threads. The cache keeps the two
    apart (the float32 ranking differs between them on the 2-core Xeon-AMX)."""
    import json

    import torch  # noqa: F401 - loaded before the counts are read (the key names its threads)

    from thintact_sdk.host.blas import openblas_threads
    from thintact_sdk.host.compute_threads import prepare_worker_thread, single_threaded_kernels
    from thintact_sdk.host.machine import kernel_threads_now

    monkeypatch.setenv("THINTACT_CACHE_DIR", str(tmp_path))
    profile = load_profile("virtual-mini")
    library = kernel_threads_now()
    get_registry().create("decoder", "t2s-closed-form", profile, {})
    with single_threaded_kernels():
        prepare_worker_thread()
        held = kernel_threads_now()
        get_registry().create("decoder", "t2s-closed-form", profile, {})
    keys = list(json.loads((tmp_path / "decoder-backends.json").read_text()))
    if openblas_threads() not in (None, 1) or library != held:
        assert held.startswith("blas 1") or openblas_threads() is None
        assert len(keys) == 2 and {k.split("|")[-2] for k in keys} == {library, held}
    else:  # a host already at one thread: one measurement serves both
        assert len(keys) == 1
