import numpy as np

from thintact_sdk.diagnosis.tactile import fit_illumination_field


def _frames(rng: np.random.Generator) -> np.ndarray:
    return 0.3 + 0.4 * rng.random((3, 24, 32, 3))


def test_concealed_linear_falloff_is_found_and_recovered() -> None:
    rng = np.random.default_rng(0)
    sim = _frames(rng)
    x = np.linspace(-1, 1, 32)[None, None, :, None]
    real = sim * (1.0 + 0.05 * x) + rng.normal(0, 0.01, sim.shape)
    fit = fit_illumination_field(real, sim, noise_sigma=0.01)
    assert fit.order == 1
    assert abs(fit.chi2_per_dof[fit.order] - 1.0) < 0.1
    assert fit.chi2_per_dof[0] > 2.0
    np.testing.assert_allclose(fit.gain[0, -1], 1.05, atol=0.01)


def test_no_field_keeps_constant_gain() -> None:
    rng = np.random.default_rng(1)
    sim = _frames(rng)
    real = sim + rng.normal(0, 0.01, sim.shape)
    fit = fit_illumination_field(real, sim, noise_sigma=0.01)
    assert fit.order == 0
    np.testing.assert_allclose(fit.gain, 1.0, atol=0.005)


def test_falloff_below_per_pixel_noise_is_still_found() -> None:
    # 0.4 % fall-off at the edge against 1 % per-pixel noise (2.5x below the noise).
    rng = np.random.default_rng(2)
    sim = 0.3 + 0.4 * rng.random((4, 48, 64, 3))
    y = np.linspace(-1, 1, 48)[None, :, None, None]
    real = sim * (1.0 - 0.004 * y) + rng.normal(0, 0.01, sim.shape)
    fit = fit_illumination_field(real, sim, noise_sigma=0.01)
    assert fit.order == 1
    assert fit.bic[0] - fit.bic[1] > 10.0
    np.testing.assert_allclose(fit.gain[-1, 0], 0.996, atol=0.0015)
