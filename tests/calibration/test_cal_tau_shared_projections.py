"""The τ sweeps decode each frame from one shared projection (issue 36): the same curves and
choices as decoding every frame afresh at every τ."""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.calibration.tau import cross_validate, noise_criteria, shared_decode, tau_grid
from thintact_sdk.reconstruction.decoders import ArrayBackend, T2SClosedFormDecoder
from thintact_sdk.reconstruction.t2s import SystemMatrices


class _PlainDecode:
    """The same decoder without ``project``: every τ decodes every frame afresh."""

    def __init__(self, inner: T2SClosedFormDecoder) -> None:
        self.inner = inner

    def set_tau(self, tau: Any) -> None:
        self.inner.set_tau(tau)

    def decode(self, y: np.ndarray) -> np.ndarray:
        return self.inner.decode(y)


def _unit() -> tuple[SystemMatrices, list[np.ndarray], list[np.ndarray]]:
    rng = np.random.default_rng(11)
    r, s, n, m = 26, 30, 10, 12

    def smooth(rows: int, cols: int) -> np.ndarray:
        return rng.random((rows, 2)) @ rng.random((2, cols)) * 2

    sm = SystemMatrices(np.stack([smooth(r, n) for _ in range(2)]), np.stack([smooth(s, m) for _ in range(2)]),
                        rng.standard_normal((2, r, n)), rng.standard_normal((2, s, m)))
    truths = [rng.random((n, m, 2)).astype(np.float32) for _ in range(6)]
    signals = [(sm.forward(x) + 0.3 * rng.standard_normal((r, s, 2))).astype(np.float32) for x in truths]
    return sm, signals, truths


def test_cross_validation_is_unchanged_by_shared_projections() -> None:
    sm, signals, truths = _unit()
    labels = [f"s{i}" for i in range(len(signals))]
    grid = tau_grid(sm)
    shared = cross_validate(T2SClosedFormDecoder(sm, 1.0, mode_rtol=0.05), "t2s", signals, truths, labels, grid)
    afresh = cross_validate(_PlainDecode(T2SClosedFormDecoder(sm, 1.0, mode_rtol=0.05)), "t2s", signals, truths,
                            labels, grid)
    assert shared is not None and afresh is not None
    assert shared.curve.taus == afresh.curve.taus
    np.testing.assert_allclose(shared.curve.values, afresh.curve.values, rtol=1e-5)
    assert shared.curve.tau == afresh.curve.tau and shared.fold_tau == afresh.fold_tau


def test_noise_criteria_are_unchanged_by_shared_projections() -> None:
    sm, signals, _ = _unit()
    inv_var = [np.full(y.shape, 1 / 0.09) for y in signals]
    grid = tau_grid(sm)[::3]
    shared = noise_criteria(T2SClosedFormDecoder(sm, 1.0, ArrayBackend("numpy", "float64")), sm, signals, inv_var, grid)
    afresh = noise_criteria(_PlainDecode(T2SClosedFormDecoder(sm, 1.0, ArrayBackend("numpy", "float64"))), sm,
                            signals, inv_var, grid)
    for a, b in zip(shared, afresh, strict=True):
        np.testing.assert_allclose(a.values, b.values, rtol=1e-6)
        assert a.tau == b.tau or (np.isnan(a.tau) and np.isnan(b.tau))


def test_shared_decode_falls_back_to_decode() -> None:
    sm, signals, _ = _unit()
    dec = _PlainDecode(T2SClosedFormDecoder(sm, 3.0))
    np.testing.assert_array_equal(shared_decode(dec, signals)(2), dec.decode(signals[2]))
