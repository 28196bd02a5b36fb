"""The virtual camera plugin: frames, noise, slot, exposure, pacing."""

from __future__ import annotations

import time

import numpy as np
import pytest
from thintact_virtual.bench import get_scene_slot, signal_scale_dn

from thintact_sdk.device.registry import get_registry
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.pixels.bayer import bin_bayer
from thintact_sdk.simulation.noise import noise_variance_dn
from thintact_sdk.simulation.scenes import make_scene
from thintact_sdk.simulation.simulator import Simulator


@pytest.fixture(scope="module")
def profile():
    return load_profile("virtual-mini")


def _camera(profile, **settings):
    comp = get_registry().components("camera")["virtual"]
    cam = comp.factory(profile, {"fps": 0, **settings})
    cam.open()
    return cam


def test_registered_and_frame_format(profile):
    cam = _camera(profile, scenes="checker", noise=False)
    f0, f1 = cam.read(), cam.read()
    assert f0.data.dtype == np.uint16 and f0.data.shape == (256, 320)
    assert f0.pixel_format == "BayerRG12" and f0.exposure_us == 10000
    assert f1.frame_id == f0.frame_id + 1 and f1.timestamp_ns >= f0.timestamp_ns
    assert f0.meta["scene"].shape == (50, 64, 3)
    cam.close()


def test_frames_bin_back_to_the_simulated_dn(profile):
    cam = _camera(profile, scenes="usaf", noise=False)
    frame = cam.read()
    sim = Simulator(profile)
    gain = signal_scale_dn(profile, {})
    want = np.round(sim.predict_dn(make_scene("usaf", 50, 64), gain))
    assert np.array_equal(bin_bayer(frame.data), want.astype(np.float32))
    white = sim.predict_signal_dn(np.ones((50, 64, 3)), gain)
    assert white.max() == pytest.approx(0.6 * (4095 - 64), rel=1e-9)


def test_noise_statistics_match_model(profile):
    cam = _camera(profile, scenes="white", noise=True, seed=7)
    clean = _camera(profile, scenes="white", noise=False)
    expected = bin_bayer(clean.read().data).astype(float)
    frames = np.stack([bin_bayer(cam.read().data).astype(float) for _ in range(12)])
    resid = frames - expected
    z = resid / np.sqrt(noise_variance_dn(expected, profile.noise))
    assert abs(z.mean()) < 0.02
    assert z.var() == pytest.approx(1.0, rel=0.05)


def test_slot_overrides_library(profile):
    key = "test-virtual-slot"
    cam = _camera(profile, scenes="white", noise=False, slot=key)
    lib = cam.read()
    scene = make_scene("checker", 50, 64)
    get_scene_slot(key).set(scene)
    try:
        shown = cam.read()
        assert np.array_equal(shown.meta["scene"], scene)
        assert not np.array_equal(shown.data, lib.data)
    finally:
        get_scene_slot(key).set(None)
    assert np.array_equal(cam.read().meta["scene"], lib.meta["scene"])


def test_exposure_scales_signal(profile):
    cam = _camera(profile, scenes="smooth_color", noise=False)
    a = bin_bayer(cam.read().data) - 64
    cam.set_exposure_us(5000)
    b = bin_bayer(cam.read().data) - 64
    assert cam.read().exposure_us == 5000
    assert np.allclose(b, a / 2, atol=1.0)
    from thintact_sdk.errors import UnsupportedFeatureError

    with pytest.raises(UnsupportedFeatureError):
        cam.set_gain_db(3.0)


def test_library_list_cycles(profile):
    cam = _camera(profile, scenes=["white", "checker"], noise=False)
    s = [cam.read().meta["scene"] for _ in range(3)]
    assert np.array_equal(s[0], s[2]) and not np.array_equal(s[0], s[1])


def test_fps_pacing(profile):
    cam = _camera(profile, scenes="white", fps=50.0)
    cam.read()
    t0 = time.monotonic()
    for _ in range(5):
        cam.read()
    assert time.monotonic() - t0 >= 4 / 50  # 5 reads after the first: >= 4 full periods


def test_unknown_scene_is_user_error(profile):
    from thintact_sdk.errors import ThinTactError

    with pytest.raises(ThinTactError, match="unknown scene"):
        _camera(profile, scenes="nope")


def test_dn_effects_apply_at_the_current_exposure(profile):
    prof = profile.with_physics({"sensor_gamma": {"gamma": 0.8}, "saturation": {"level_dn": 1500.0}})
    cam = _camera(prof, scenes="white", noise=False)
    full = bin_bayer(cam.read().data)
    assert full.max() == 1500.0
    cam.set_exposure_us(2500)
    quarter = bin_bayer(cam.read().data).astype(float) - 64
    sim = Simulator(prof)
    gain = signal_scale_dn(prof, {}) * 0.25
    want = np.round(sim.predict_dn(np.ones((50, 64, 3)), gain)) - 64
    assert np.array_equal(quarter, want)
    lin = Simulator(profile).predict_signal_dn(np.ones((50, 64, 3)), gain)
    fs = 4095 - 64
    assert np.allclose(quarter, np.round(fs * (lin / fs) ** 0.8), atol=1.0)


def test_a_rate_too_slow_to_pace_and_a_white_level_beyond_16_bits_are_refused():
    """fps 1e-300 overflowed int(1e9 / fps) on the first read; a saturation of 1e6 DN wrapped
    around in the uint16 raw frames."""
    from thintact_sdk.errors import ThinTactError

    prof = load_profile("virtual-mini")
    with pytest.raises(ThinTactError, match="fps 1e-300"):
        _camera(prof, fps=1e-300)
    bright = prof.model_copy(update={"noise": prof.noise.model_copy(update={"saturation_dn": 1e6})})
    with pytest.raises(ThinTactError, match="16-bit raw frames"):
        _camera(bright)
