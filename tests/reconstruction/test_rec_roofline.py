"""Work the closed-form decoders skip (negligible Tikhonov modes, product order) and the
roofline figures the bench reports."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.host.roofline import measure_sgemm_gflops, roofline_ratio
from thintact_sdk.reconstruction.decoders import (
    ArrayBackend,
    FlatCamDecoder,
    NonIterativeDecoder,
    T2SClosedFormDecoder,
)
from thintact_sdk.reconstruction.decoders.backend import synthesis_macs
from thintact_sdk.reconstruction.decoders.modes import kept_mode_counts
from thintact_sdk.reconstruction.synthetic_matrices import frequency_split_matrices
from thintact_sdk.reconstruction.t2s import SystemMatrices


def _decaying(a: np.ndarray) -> np.ndarray:
    """``a`` with its singular values replaced by 10 · 0.7^i (a blur-like spectrum)."""
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    return (u * (10.0 * 0.7 ** np.arange(len(s)))) @ vt


@pytest.fixture(scope="module")
def operator():
    sm, jf = frequency_split_matrices((64, 72), (20, 24), (8, 9), seed=1)
    sm = SystemMatrices(sm.Po, sm.Qo, np.stack([_decaying(p) for p in sm.Pc]),
                        np.stack([_decaying(q) for q in sm.Qc]), dict(sm.meta))
    x = np.random.default_rng(0).random((20, 24, 3))
    return sm, jf, x, sm.forward(x).astype(np.float32)


def test_kept_modes_follow_the_filter_factor() -> None:
    sp = np.array([[10.0, 1.0, 0.1, 0.01]])
    sq = np.array([[10.0, 1.0, 0.1]])
    # factor of P-mode i at σ_Q,max = 10: 100 σ² / (100 σ² + τ) = 1.0, 0.99, 0.5, 0.0099 (τ = 1)
    assert kept_mode_counts(sp, sq, 1.0, 0.0) == (4, 3)
    assert kept_mode_counts(sp, sq, 1.0, 1e-3) == (4, 3)
    assert kept_mode_counts(sp, sq, 1.0, 0.05) == (3, 3)
    assert kept_mode_counts(sp, sq, 1.0, 0.6) == (2, 2)
    assert kept_mode_counts(sp, sq, 1e6, 0.5) == (1, 1)
    assert kept_mode_counts(np.vstack([sp, sp * 10]), np.vstack([sq, sq]), 1.0, 1e-3) == (4, 3)


@pytest.mark.parametrize("make", [
    lambda sm, jf, tau, rtol: NonIterativeDecoder(sm, jf, tau, ArrayBackend("numpy", "float64"), mode_rtol=rtol),
    lambda sm, jf, tau, rtol: T2SClosedFormDecoder(sm, tau, ArrayBackend("numpy", "float64"), mode_rtol=rtol),
    lambda sm, jf, tau, rtol: FlatCamDecoder(sm, tau, ArrayBackend("numpy", "float64"), mode_rtol=rtol),
])
def test_dropping_negligible_modes_costs_less_work_and_almost_nothing_in_the_result(operator, make) -> None:
    sm, jf, x, y = operator
    full, cut = make(sm, jf, 100.0, 0.0), make(sm, jf, 100.0, 1e-2)
    assert full.kept_modes == (20, 24)
    assert cut.kept_modes[0] < 20 and cut.kept_modes[1] < 24
    assert cut.gemm_flops() < full.gemm_flops()
    a, b = full.decode(y), cut.decode(y)
    assert np.linalg.norm(a - b) <= 0.02 * np.linalg.norm(a)


def test_set_tau_restores_modes_a_smaller_tau_needs(operator) -> None:
    sm, jf, x, y = operator
    be = ArrayBackend("numpy", "float64")
    dec = T2SClosedFormDecoder(sm, 1e3, be, mode_rtol=1e-2)
    small = dec.kept_modes
    dec.set_tau(1e-3)
    assert dec.kept_modes == T2SClosedFormDecoder(sm, 1e-3, be, mode_rtol=1e-2).kept_modes != small


def test_synthesis_order_is_the_cheaper_and_exact() -> None:
    assert synthesis_macs(400, 300, 380, 512) == min(400 * 380 * (300 + 512), 300 * 512 * (380 + 400))
    rng = np.random.default_rng(2)
    be = ArrayBackend("numpy", "float64")
    for n, kp, kq, m in ((10, 4, 9, 12), (10, 9, 4, 12)):
        vp, coef, vqt = rng.random((2, n, kp)), rng.random((2, kp, kq)), rng.random((2, kq, m))
        np.testing.assert_allclose(be.synthesise(vp, coef, vqt), np.moveaxis(vp @ coef @ vqt, 0, -1), rtol=1e-6)


def test_roofline_ratio() -> None:
    assert roofline_ratio(20.0, 2e9, 100.0) == pytest.approx(1.0)
    assert measure_sgemm_gflops(1, 64, 64, 64, repeats=2) > 0


@pytest.mark.parametrize("rtol", [0.0, 1e-2])
def test_black_level_folds_in_exactly_with_modes_dropped_and_after_a_new_tau(rtol) -> None:
    """The T2S closed form carries the pedestal as a rank-one term (no unit frame decoded):
    ``decode(y + b, b) == decode(y)`` whatever modes are kept, also after ``set_tau``.
    Positive coding matrices (a binary mask's), so the coding term sees the pedestal."""
    rng = np.random.default_rng(5)
    sm = SystemMatrices(0.2 * rng.random((3, 64, 20)), 0.2 * rng.random((3, 72, 24)),
                        np.stack([_decaying(p) for p in rng.random((3, 64, 20))]),
                        np.stack([_decaying(q) for q in rng.random((3, 72, 24))]))
    y = sm.forward(rng.random((20, 24, 3)))
    for tau in (100.0, 3.0):
        dec = T2SClosedFormDecoder(sm, 1e3, ArrayBackend("numpy", "float64"), mode_rtol=rtol)
        dec.set_tau(tau)
        fresh = T2SClosedFormDecoder(sm, tau, ArrayBackend("numpy", "float64"), mode_rtol=rtol)
        assert dec.kept_modes == fresh.kept_modes
        want = fresh.decode(y)
        # float64 solve, float32 result: equal to the result's rounding
        np.testing.assert_allclose(dec.decode(y + 64.0, 64.0), want, rtol=1e-5, atol=1e-6 * np.abs(want).max())
