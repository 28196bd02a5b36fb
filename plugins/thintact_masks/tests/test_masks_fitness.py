"""The paper's fitness: metric parts, noise model, determinism."""

from __future__ import annotations

import numpy as np
import pytest
from thintact_masks.fitness import (
    FitnessEvaluator,
    FitnessSettings,
    SSIMReference,
    combine,
    f_grad,
    f_ssim,
)

from thintact_sdk.reconstruction.metrics import ssim


def test_cached_ssim_equals_the_shared_metric() -> None:
    rng = np.random.default_rng(0)
    truth, est = rng.random((30, 40)), rng.random((30, 40))
    assert SSIMReference(truth)(est) == pytest.approx(ssim(est, truth), abs=1e-12)
    assert SSIMReference(np.ones((30, 40)))(est) == pytest.approx(ssim(est, np.ones((30, 40))),
                                                                 abs=1e-12)


def test_fitness_formula() -> None:
    parts = {"ssim_usaf": 0.5, "ssim_white": 0.75, "psnr_usaf": 20.0, "psnr_white": 30.0,
             "f_grad": 7.0}
    fu, fw = 2.0, 4.0
    assert combine(parts) == pytest.approx(2 * fu * fw / (fu + fw) + 25.0 + 7.0)
    assert f_ssim(1.0) > 1e8
    img = np.zeros((4, 5))
    img[:, 2:] = 1.0  # one vertical edge: ‖G_u‖₁ = 4
    assert f_grad(img) == pytest.approx(2 * 20 / 4)


def test_noiseless_reconstruction_is_nearly_exact(tiny_profile) -> None:
    ev = FitnessEvaluator(tiny_profile, 40, FitnessSettings(noise=False, tau=1e-14))
    rec = ev.reconstruct(np.asarray(tiny_profile.mask.phi))
    for name, x in ev.scenes.items():
        np.testing.assert_allclose(rec[name], x, atol=1e-4)


def test_noise_lowers_quality_and_is_deterministic(tiny_profile) -> None:
    phi = np.asarray(tiny_profile.mask.phi)
    clean = FitnessEvaluator(tiny_profile, 40, FitnessSettings(noise=False, tau=1e-6))
    noisy = FitnessEvaluator(tiny_profile, 40, FitnessSettings(frames_averaged=1, tau=1e-6))
    assert noisy.evaluate(phi).parts["psnr_usaf"] < clean.evaluate(phi).parts["psnr_usaf"]
    again = FitnessEvaluator(tiny_profile, 40, FitnessSettings(frames_averaged=1, tau=1e-6))
    assert again.fitness(phi) == noisy.fitness(phi)
    # more averaged frames: less noise
    avg = FitnessEvaluator(tiny_profile, 40, FitnessSettings(frames_averaged=100))
    assert avg.sigma_rel["white"] == pytest.approx(noisy.sigma_rel["white"] / 10)


def test_float32_agrees_with_float64(tiny_profile) -> None:
    phi = np.asarray(tiny_profile.mask.phi)
    f64 = FitnessEvaluator(tiny_profile, 40).fitness(phi)
    f32 = FitnessEvaluator(tiny_profile, 40, FitnessSettings(dtype="float32")).fitness(phi)
    assert f32 == pytest.approx(f64, rel=1e-3)


def test_wrong_length_and_bad_settings_are_refused(tiny_profile) -> None:
    ev = FitnessEvaluator(tiny_profile, 40)
    with pytest.raises(ValueError, match="shape"):
        ev.fitness(np.ones(39))
    with pytest.raises(ValueError, match="frames_averaged"):
        FitnessEvaluator(tiny_profile, 40, FitnessSettings(frames_averaged=0))
