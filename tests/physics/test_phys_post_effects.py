"""Scene, signal and DN effects, the registry and resolve_physics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.simulation.effects import EFFECTS, resolve_physics, stray_light
from thintact_sdk.simulation.simulator import Simulator

CONTRACT_EFFECTS = {
    "diffraction": ["wavelength_nm"], "pixel_angular_response": ["exponent"],
    "refraction": ["n_scene_side"], "mask_misalignment": ["angle_deg", "dx_um", "dy_um"],
    "mask_leakage": ["transmittance"], "geometry": ["scene_to_mask_mm", "mask_to_sensor_mm"],
    "sensor_gamma": ["gamma"], "saturation": ["level_dn"], "sensor_blur": ["sigma_um"],
    "scene_blur": ["sigma_um"], "display_gamma": ["gamma"], "color_crosstalk": ["matrix"],
    "veiling_glare": ["fraction"], "stray_light": ["mean_dn"],
}


@pytest.fixture(scope="module")
def mini():
    return load_profile("virtual-mini")


@pytest.fixture(scope="module")
def scenes():
    return np.random.default_rng(21).random((2, 50, 64, 3))


@pytest.fixture(scope="module")
def base(mini, scenes):
    return Simulator(mini).forward_batch(scenes)


def test_registry_covers_contract_vocabulary():
    assert set(EFFECTS) == set(CONTRACT_EFFECTS)
    for name, params in CONTRACT_EFFECTS.items():
        spec = EFFECTS[name]
        assert list(spec.params) == params and spec.description and spec.stage in (
            "scene", "kernel", "signal", "dn")
        for p in spec.params.values():
            assert p.unit and p.bounds[0] <= p.bounds[1]


@pytest.mark.parametrize("physics,match", [
    ({"fog": {}}, "unknown effect"),
    ({"sensor_gamma": {"gama": 1.0}}, "unknown parameter"),
    ({"mask_leakage": {"transmittance": 2.0}}, "outside the physical range"),
    ({"diffraction": {"wavelength_nm": [500, 500]}}, "shape"),
    ({"color_crosstalk": {"matrix": [[0.9, 0, 0], [0, 1, 0], [0, 0, 1]]}}, "diagonal"),
    # values numpy cannot make a float of (these raised TypeError/OverflowError: exit 1)
    ({"display_gamma": {"gamma": {"a": 1}}}, "gamma: expected a number"),
    ({"display_gamma": {"gamma": 10**400}}, "gamma: expected a number"),
    ({"display_gamma": {"gamma": "fast"}}, "gamma: expected a number"),
    ({"diffraction": {"wavelength_nm": [500, [1, 2], 600]}}, "wavelength_nm: expected numbers of shape"),
])
def test_resolve_physics_refuses_bad_entries(physics, match):
    with pytest.raises(ThinTactError, match=match):
        resolve_physics(physics)


def test_resolve_fills_defaults():
    r = resolve_physics({"mask_misalignment": {"angle_deg": 0.3}})
    assert r == {"mask_misalignment": {"angle_deg": 0.3, "dx_um": 0.0, "dy_um": 0.0}}


def test_neutral_parameters_are_identity(mini, scenes, base):
    neutral = {name: {} for name in ("display_gamma", "scene_blur", "sensor_blur", "color_crosstalk",
                                     "veiling_glare", "stray_light", "sensor_gamma", "saturation")}
    assert np.allclose(Simulator(mini.with_physics(neutral)).forward_batch(scenes), base, rtol=1e-12)


def test_display_gamma_acts_on_scene(mini, scenes):
    y = Simulator(mini.with_physics({"display_gamma": {"gamma": 2.2}})).forward_batch(scenes)
    assert np.allclose(y, Simulator(mini).forward_batch(scenes**2.2), rtol=1e-12)


def pixel_blur_brute_force(a, sigma_px, up=16):
    """Independent reference: upsample the pixel-integrated image ``up``× (piecewise constant),
    blur the fine image with a sampled Gaussian, integrate back over the pixels."""
    fine = np.repeat(np.repeat(a, up, axis=1), up, axis=2)
    fine = gaussian_filter(fine, sigma=(0, sigma_px * up, sigma_px * up, 0), mode="reflect", truncate=6)
    f, r, c, ch = a.shape
    return fine.reshape(f, r, up, c, up, ch).mean(axis=(2, 4))


def test_pixel_blur_integrates_over_pixels():
    from thintact_sdk.simulation.effects._blur import blur_pixels, pixel_gaussian_weights

    rng = np.random.default_rng(3)
    a = rng.random((1, 12, 14, 1))
    for sigma_px in (0.3, 1.0, 2.5):
        assert np.allclose(blur_pixels(a, sigma_px, (1, 2)), pixel_blur_brute_force(a, sigma_px), atol=2e-3)
    # a 3 um blur on 10 um pixels moves sigma/(sqrt(2 pi) pitch) ~ 12 % into each neighbour
    w = pixel_gaussian_weights(0.3)
    assert abs(w[len(w) // 2 + 1] - 0.3 / np.sqrt(2 * np.pi)) < 0.005


def test_scene_blur_acts_on_scene_and_stays_separable(mini, scenes):
    sim = Simulator(mini.with_physics({"scene_blur": {"sigma_um": 63.0}}))
    blurred = pixel_blur_brute_force(scenes, 2.0)
    y = sim.forward_batch(scenes)
    assert np.allclose(y, Simulator(mini).forward_batch(blurred), rtol=2e-3, atol=2e-3 * np.abs(y).max())
    terms = sim.separable_terms(1)
    assert np.allclose(sum(p @ scenes[0, ..., 1] @ q.T for p, q in terms), y[0, ..., 1], rtol=1e-9)


def test_sensor_blur_and_glare(mini, scenes, base):
    sim = Simulator(mini.with_physics({"sensor_blur": {"sigma_um": 15.0},
                                       "veiling_glare": {"fraction": 0.1}}))
    y = sim.forward_batch(scenes)
    # independent reference: scipy's Gaussian filter, weights sampled at the pixel offsets
    b = gaussian_filter(base, sigma=(0, 1.5, 1.5, 0), mode="reflect", truncate=6)
    expect = b + 0.1 * b.mean(axis=(1, 2), keepdims=True)
    assert np.allclose(y, expect, rtol=1e-6, atol=1e-6 * np.abs(expect).max())
    terms = sim.separable_terms(2)
    assert np.allclose(sum(p @ scenes[1, ..., 2] @ q.T for p, q in terms), y[1, ..., 2], rtol=1e-9)


def test_color_crosstalk_mixes_channels(mini, scenes, base):
    m = [[1.0, 0.05, 0.0], [0.02, 1.0, 0.03], [0.0, 0.1, 1.0]]
    sim = Simulator(mini.with_physics({"color_crosstalk": {"matrix": m}}))
    assert np.allclose(sim.forward_batch(scenes), base @ np.asarray(m).T, rtol=1e-12)
    with pytest.raises(ThinTactError, match="not separable"):
        sim.separable_terms(0)


def test_dn_effects_take_the_gain(mini, scenes, base):
    gain = np.array([20000.0, 21000.0, 19000.0])
    lin = base * gain
    fs = 4095 - 64
    sim = Simulator(mini.with_physics({"stray_light": {"mean_dn": [30.0, 20.0, 10.0]},
                                       "sensor_gamma": {"gamma": 0.9},
                                       "saturation": {"level_dn": 2500.0}}))
    shape = stray_light.shape(128, 160)
    assert shape.mean() == pytest.approx(1.0)
    want = lin + shape[None, :, :, None] * np.array([30.0, 20.0, 10.0])
    want = np.minimum(fs * (want / fs) ** 0.9, 2500.0 - 64)
    assert np.allclose(sim.predict_signal_dn(scenes, gain), want, rtol=1e-12)
    dn = sim.predict_dn(scenes, gain)
    assert dn.max() <= 2500.0 and np.allclose(dn, want + 64)
    # forward applies them at the reference gain and divides it back out
    g = sim.reference_gain()
    assert np.allclose(sim.forward_batch(scenes), sim.predict_signal_dn(scenes, g) / g)


def test_stray_light_mean_is_mean_dn(mini, scenes):
    sim = Simulator(mini.with_physics({"stray_light": {"mean_dn": [12.0, 0.0, 5.0]}}))
    extra = sim.predict_signal_dn(scenes, 1000.0) - Simulator(mini).predict_signal_dn(scenes, 1000.0)
    assert np.allclose(extra.mean(axis=(0, 1, 2)), [12.0, 0.0, 5.0])
    assert extra[0, 64, 80, 0] > extra[0, 0, 0, 0]


def test_changing_post_effects_reuses_the_kernel(mini, scenes):
    import time

    Simulator(mini).forward_batch(scenes)
    t0 = time.perf_counter()
    for g in (0.8, 0.9, 1.1):
        Simulator(mini.with_physics({"sensor_gamma": {"gamma": g}})).predict_dn(scenes, 2e4)
    assert time.perf_counter() - t0 < 3.0


def test_sensor_blur_is_sampled_at_the_pixel_offsets():
    """The independent renderer's convention (issue 34): a 4 um blur on 10 um pixels moves
    exp(-1/(2·0.4²)) / Σ of the light into each neighbour (4.04 %), a 3 um one 0.4 %; the
    scene blur keeps the weights integrated over its (piecewise-constant) pixels."""
    from thintact_sdk.simulation.effects import scene_blur, sensor_blur

    one = np.zeros((1, 9, 9, 1))
    one[0, 4, 4, 0] = 1.0
    row = sensor_blur.apply(one, 4.0, 10.0)[0, 4, :, 0] / sensor_blur.apply(one, 4.0, 10.0)[0, 4].sum()
    x = np.arange(-4, 5)
    g = np.exp(-0.5 * (x / 0.4) ** 2)
    assert np.allclose(row, g / g.sum(), atol=1e-12)
    assert row[5] == pytest.approx(0.0404, abs=5e-5)
    assert sensor_blur.apply(one, 3.0, 10.0)[0, 4, 5, 0] / sensor_blur.apply(one, 3.0, 10.0)[0, 4].sum() \
        == pytest.approx(0.0037, abs=2e-4)
    # the scene blur: 3 um over 10 um pixels moves sigma/(sqrt(2 pi) pitch) ~ 12 %
    s_row = scene_blur.apply(one, 3.0, 10.0)[0, 4, :, 0]
    assert s_row[5] / s_row.sum() == pytest.approx(0.3 / np.sqrt(2 * np.pi), abs=0.005)


@pytest.mark.parametrize("block", [2, 4])
def test_sensor_blur_on_blocks_is_the_fine_blur_binned(block):
    """On a binned copy (``sensor.block_pixels``) the weights are the fine pixels' sampled
    weights summed over the blocks: exact for a signal uniform within each block."""
    from thintact_sdk.simulation.effects._blur import blur_pixels

    rng = np.random.default_rng(2)
    coarse = rng.random((1, 6, 7, 1))
    fine = np.repeat(np.repeat(coarse, block, axis=1), block, axis=2)
    sigma_fine = 1.3
    blurred = blur_pixels(fine, sigma_fine, (1, 2), "sampled")
    binned = blurred.reshape(1, 6, block, 7, block, 1).mean(axis=(2, 4))
    on_blocks = blur_pixels(coarse, sigma_fine / block, (1, 2), "sampled", block)
    # interior blocks (the mirrored edges differ between the two grids by design)
    assert np.allclose(on_blocks[:, 2:-2, 2:-2], binned[:, 2:-2, 2:-2], atol=1e-12)
