"""The τ sweeps decode each frame from one shared projection (issue 36): the same curves and
choices as decoding every frame afresh at every τ."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

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


def test_noise_criteria_equal_the_float64_definition() -> None:
    # the residuals and traces are taken in float32, one product per channel (issue 36): the
    # curves of the float64 definition to far better than their 4 reported digits
    sm, signals, _ = _unit()
    inv_var = [np.full(y.shape, 1 / 0.09) for y in signals]
    grid = tau_grid(sm)[::3]
    dec = T2SClosedFormDecoder(sm, 1.0, ArrayBackend("numpy", "float64"))
    gcv, disc = noise_criteria(dec, sm, signals, inv_var, grid)
    rng = np.random.default_rng(0)
    zs = [rng.choice(np.array([-1.0, 1.0], np.float32), size=signals[0].shape) for _ in range(4)]
    n = float(signals[0].size)
    for j, tau in enumerate(grid):
        dec.set_tau(float(tau))
        chi2 = np.mean([np.sum((y - sm.forward(np.asarray(dec.decode(y), np.float64))) ** 2 * w) / y.size
                        for y, w in zip(signals, inv_var, strict=True)])
        trace = np.mean([np.sum(z * sm.forward(np.asarray(dec.decode(z), np.float64))) for z in zs])
        assert disc.values[j] == pytest.approx(chi2, rel=1e-4)
        assert gcv.values[j] == pytest.approx(chi2 / (1 - min(trace, n - 1) / n) ** 2, rel=1e-4)


def test_a_sensor_binned_decoder_sweeps_from_one_projection_too() -> None:
    # the binned backend (a calibration candidate on oversampling sensors) bins each frame and
    # projects it once per sweep (issue 36: it binned and projected every frame at every τ)
    from thintact_sdk.reconstruction.decoders.sensor_binning import (
        SensorBinnedDecoder,
        bin_system_matrices,
    )

    sm, signals, truths = _unit()
    inner = T2SClosedFormDecoder(bin_system_matrices(sm, 2), 1.0, mode_rtol=0.05)
    dec = SensorBinnedDecoder(inner, sm.sensor_shape, sm.channels, 2)
    decode = shared_decode(dec, signals)
    for tau in tau_grid(sm)[::4]:
        dec.set_tau(float(tau))
        for i, y in enumerate(signals):
            np.testing.assert_allclose(decode(i), dec.decode(y), rtol=1e-4, atol=1e-5)
    labels = [f"s{i}" for i in range(len(signals))]
    shared = cross_validate(dec, "t2s", signals, truths, labels, tau_grid(sm))
    afresh = cross_validate(_PlainDecode(dec), "t2s", signals, truths, labels, tau_grid(sm))  # type: ignore[arg-type]
    assert shared is not None and afresh is not None
    np.testing.assert_allclose(shared.curve.values, afresh.curve.values, rtol=1e-5)
    assert shared.curve.tau == afresh.curve.tau


def test_noise_criteria_take_the_weights_as_a_function_of_the_signal() -> None:
    # the calibration passes 1/σ²(y) as a function, so that no float64 list of weights (440 MB
    # at the paper's size) is held beside their float32 copies (issue 36)
    sm, signals, _ = _unit()
    grid = tau_grid(sm)[::3]

    def weight(y: np.ndarray) -> np.ndarray:
        return 1.0 / (0.05 + 0.01 * np.clip(np.asarray(y, np.float64), 0.0, None))

    dec = T2SClosedFormDecoder(sm, 1.0, ArrayBackend("numpy", "float64"))
    listed = noise_criteria(dec, sm, signals, [weight(y) for y in signals], grid)
    lazily = noise_criteria(dec, sm, signals, weight, grid)
    for a, b in zip(listed, lazily, strict=True):
        assert a.values == b.values and (a.tau == b.tau or (np.isnan(a.tau) and np.isnan(b.tau)))
