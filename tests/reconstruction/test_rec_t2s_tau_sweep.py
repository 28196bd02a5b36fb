"""t2s-closed-form's cheap τ change (issue 36): ``set_tau`` on precomputed factors and decoding
from shared projections give what a decoder built at that τ gives."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.reconstruction.decoders import ArrayBackend, T2SClosedFormDecoder
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices

TAUS = (0.03, 1.0, 40.0, 3000.0, 2e5)


def _matrices(seed: int) -> SystemMatrices:
    """Small T2S matrices with an open part of rank 3 per axis."""
    rng = np.random.default_rng(seed)
    r, s, n, m = 28, 32, 11, 13

    def smooth(rows: int, cols: int) -> np.ndarray:
        return rng.random((rows, 3)) @ rng.random((3, cols)) * 2

    return SystemMatrices(np.stack([smooth(r, n) for _ in range(2)]), np.stack([smooth(s, m) for _ in range(2)]),
                          rng.standard_normal((2, r, n)), rng.standard_normal((2, s, m)))


def _einsum_small_inverse(part: tuple[np.ndarray, ...], kp: int, kq: int, tau: float) -> np.ndarray:
    """The small system ``(Mmid⁻¹ + Wᵀ Hc⁻¹ W)⁻¹`` written as the five-index sum, for reference."""
    a_all, b_all, d, sig2 = part
    k = kp * kq
    t = np.einsum("ab,ai,ak,bj,bl->ijkl", 1.0 / (sig2 + tau), a_all, a_all, b_all, b_all)
    gram = np.block([[t[:kp, :kq, :kp, :kq].reshape(k, k), t[:kp, :kq, kp:, kq:].reshape(k, k)],
                     [t[kp:, kq:, :kp, :kq].reshape(k, k), t[kp:, kq:, kp:, kq:].reshape(k, k)]])
    eye = np.eye(k)
    return np.asarray(np.linalg.inv(np.block([[np.zeros((k, k)), eye], [eye, -np.diag(d.ravel())]]) + gram))


def test_gram_factors_give_the_five_index_sum() -> None:
    dec = T2SClosedFormDecoder(_matrices(1), 1.0, ArrayBackend("numpy", "float64"))
    for c, part in enumerate(dec._parts):
        for tau in TAUS:
            got = dec._grams[c].small_inverse(tau)
            want = _einsum_small_inverse(part, dec._kp, dec._kq, tau)
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())


@pytest.mark.parametrize("prior", [None, ScenePrior(1.0, 3.0)])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_set_tau_then_decode_equals_a_decoder_built_at_that_tau(prior: ScenePrior | None, dtype: str) -> None:
    sm = _matrices(2)
    rng = np.random.default_rng(3)
    y = sm.forward(rng.random((*sm.scene_shape, 2))) + rng.standard_normal((*sm.sensor_shape, 2))
    y = y.astype(dtype)
    swept = T2SClosedFormDecoder(sm, 1.0, ArrayBackend("numpy", dtype), mode_rtol=0.05, prior=prior)
    tol = 1e-6 if dtype == "float64" else 2e-4
    kept = set()
    for tau in (*TAUS, *TAUS[::-1]):
        swept.set_tau(tau)
        fresh = T2SClosedFormDecoder(sm, tau, ArrayBackend("numpy", dtype), mode_rtol=0.05, prior=prior)
        assert swept.kept_modes == fresh.kept_modes
        kept.add(swept.kept_modes)
        want = fresh.decode(y)
        np.testing.assert_allclose(swept.decode(y), want, rtol=0, atol=tol * np.abs(want).max())
        np.testing.assert_allclose(swept.decode(y, 5.0), fresh.decode(y, 5.0), rtol=0,
                                   atol=tol * np.abs(want).max())
    assert len(kept) > 1  # the sweep crossed τ where the coding modes kept change


@pytest.mark.parametrize("backend", [("numpy", "float64"), ("numpy", "float32"), ("torch", "float64")])
def test_decoding_from_shared_projections_is_decode(backend: tuple[str, str]) -> None:
    sm = _matrices(4)
    rng = np.random.default_rng(5)
    y = (sm.forward(rng.random((*sm.scene_shape, 2))) + rng.standard_normal((*sm.sensor_shape, 2))).astype(backend[1])
    dec = T2SClosedFormDecoder(sm, 1.0, ArrayBackend(*backend), mode_rtol=0.05)
    projected = dec.project(y)
    tol = 1e-10 if backend[1] == "float64" else 2e-5
    for tau in TAUS:
        dec.set_tau(tau)
        want = np.asarray(dec.decode(y))
        got = np.asarray(dec.decode_projected(projected))
        np.testing.assert_allclose(got, want, rtol=0, atol=tol * np.abs(want).max())

