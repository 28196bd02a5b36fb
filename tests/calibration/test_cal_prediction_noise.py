"""Issue 36: the design prediction's slit noise is drawn in float32 with the same mean and
variance as the sensor model (:func:`~thintact_sdk.simulation.noise.signal_to_dn`), Gaussian
only where shot + read noise is nearly symmetric, exact Poisson elsewhere."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.calibration.prediction import GAUSSIAN_SKEW_LIMIT, slit_dn
from thintact_sdk.formats.profiles import NoiseSpec
from thintact_sdk.simulation.noise import (
    QUANTISATION_VARIANCE_DN2,
    signal_to_dn,
    signal_variance_dn,
)


@pytest.mark.parametrize("read", [2.0, 0.3])
@pytest.mark.parametrize("signal", [0.0, 0.5, 3.0, 40.0, 900.0])
def test_slit_noise_has_the_sensor_models_mean_and_variance(read: float, signal: float) -> None:
    noise = NoiseSpec(black_level_dn=64.0, read_noise_dn=read, electrons_per_dn=4.0, saturation_dn=4095.0)
    n = 400_000
    got = slit_dn(np.full(n, signal), noise, np.random.default_rng(1)).astype(np.float64)
    ref = signal_to_dn(np.full(n, signal), noise, np.random.default_rng(2))
    var = float(signal_variance_dn(signal, noise)) + QUANTISATION_VARIANCE_DN2
    se_mean, se_var = np.sqrt(var / n), var * np.sqrt(2.0 / n)
    assert np.all(got == np.round(got))
    assert abs(got.mean() - ref.mean()) < 6 * se_mean
    assert abs(got.var() - ref.var()) < 8 * se_var + 0.02  # rounding of a narrow law: not exactly 1/12


def test_skewed_pixels_are_drawn_from_the_exact_poisson_law() -> None:
    # no read noise, one electron per DN: a low signal is Poisson, integer electrons
    noise = NoiseSpec(black_level_dn=0.0, read_noise_dn=0.0, electrons_per_dn=1.0, saturation_dn=4095.0)
    got = slit_dn(np.full(200_000, 2.0), noise, np.random.default_rng(3))
    assert got.dtype == np.float32
    assert np.mean(got == 0) == pytest.approx(np.exp(-2.0), abs=0.005)
    assert np.mean(got == 1) == pytest.approx(2.0 * np.exp(-2.0), abs=0.005)
    # a signal whose skewness 1/sqrt(λ) is below the limit is drawn Gaussian with λ's variance
    lam = 4.0 / GAUSSIAN_SKEW_LIMIT**2
    big = slit_dn(np.full(200_000, lam), noise, np.random.default_rng(4)).astype(np.float64)
    assert big.mean() == pytest.approx(lam, abs=0.1)
    assert big.var() == pytest.approx(lam + QUANTISATION_VARIANCE_DN2, rel=0.02)


def test_clipped_to_the_sensor_range() -> None:
    noise = NoiseSpec(black_level_dn=64.0, read_noise_dn=2.0, electrons_per_dn=4.0, saturation_dn=4095.0)
    got = slit_dn(np.array([-50.0, 0.0, 5000.0]), noise, np.random.default_rng(5))
    assert got[2] == 4095.0 and 0.0 <= got[0] <= 100.0


@pytest.mark.parametrize("read_e", [3.7, 3.84, 3.86, 4.2, 9.0])
def test_the_skipped_exact_test_would_have_found_nothing(read_e: float) -> None:
    # where the skewness bound says no pixel can be exact, the elementwise test is skipped
    # (issue 36: it cost a third of the design's noise draws); it would have found nothing there
    noise = NoiseSpec(black_level_dn=64.0, read_noise_dn=read_e, electrons_per_dn=1.0, saturation_dn=65535.0)
    lam = np.geomspace(1e-3, 1e4, 200_001).astype(np.float32)
    a = np.float32(read_e**2)
    exact = (lam > 0) & (lam > np.float32(GAUSSIAN_SKEW_LIMIT) * (lam + a) ** np.float32(1.5))
    got = slit_dn(lam, noise, np.random.default_rng(6))
    z = np.random.default_rng(6).standard_normal(lam.shape, dtype=np.float32)
    gaussian = np.clip(np.round(lam + np.sqrt(lam + a) * z + np.float32(64.0)), 0, 65535)
    if exact.any():  # below the bound: the exact pixels are drawn Poisson, the rest as before
        assert read_e < 0.385 / GAUSSIAN_SKEW_LIMIT
        np.testing.assert_array_equal(got[~exact], gaussian[~exact])
    else:
        np.testing.assert_array_equal(got, gaussian)
