"""Decoders on torch CUDA: the same results as numpy, and chosen automatically when present.
Skipped cleanly on a host without a CUDA device (torch CPU builds included)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this host")


def test_cuda_is_a_candidate_and_decodes_like_numpy() -> None:
    from thintact_sdk.host.machine import host_capabilities
    from thintact_sdk.reconstruction.decoders import (
        ArrayBackend,
        NonIterativeDecoder,
        T2SClosedFormDecoder,
    )
    from thintact_sdk.reconstruction.decoders.backend_candidates import candidate_specs
    from thintact_sdk.reconstruction.synthetic_matrices import frequency_split_matrices

    assert "cuda-float32" in [s.key for s in candidate_specs(host_capabilities())]
    sm, jf = frequency_split_matrices((64, 72), (20, 24), (8, 9), seed=1)
    x = np.random.default_rng(0).random((20, 24, 3)).astype(np.float32)
    raw = np.round(sm.forward(x) + 64.0).astype(np.uint16)
    for make in (lambda be: NonIterativeDecoder(sm, jf, 1e-3, be), lambda be: T2SClosedFormDecoder(sm, 1e-3, be)):
        ref = make(ArrayBackend("numpy", "float64")).decode(raw, 64.0)
        gpu = make(ArrayBackend("torch", "float32", device="cuda")).decode(raw, 64.0)
        assert np.abs(gpu - ref).max() <= 1e-3 * np.abs(ref).max()


def test_registry_decoder_measures_cuda(monkeypatch, tmp_path) -> None:
    from thintact_sdk.device.registry import get_registry
    from thintact_sdk.formats.profiles import load_profile

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    profile = load_profile("virtual-finger")
    dec = get_registry().create("decoder", "t2s-closed-form", profile, {})
    assert "cuda-float32" in dec.backend_choice.measured_ms
