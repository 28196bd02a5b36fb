"""The capture helper: raw frame → measurement, drop counting, camera creation errors."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from thintact_sdk.device.cameras import (
    DroppedFramesWarning,
    FrameGapCounter,
    bit_depth_problem,
    create_camera,
    pixel_format_bits,
    to_measurement,
)
from thintact_sdk.errors import DeviceError, PluginError, ProfileError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.frames import RawFrame
from thintact_sdk.pixels.bayer import mosaic_from_rgb


@pytest.fixture()
def profile():
    return load_profile("virtual-mini")


def _rgb(profile, seed=0):
    rng = np.random.default_rng(seed)
    shape = (profile.sensor.rows, profile.sensor.cols, 3)
    return rng.integers(64, 4095, size=shape).astype(np.uint16)


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_mosaic_bins_back_exactly(profile, pattern):
    rgb = _rgb(profile)
    raw = RawFrame(mosaic_from_rgb(rgb, pattern), 123, 7, pixel_format=f"Bayer{pattern[:2]}12",
                   exposure_us=5000.0, gain_db=1.5, device_timestamp_ns=99)
    if pattern in ("GRBG", "GBRG"):
        raw.pixel_format = {"GRBG": "BayerGR12", "GBRG": "BayerGB12"}[pattern]
    m = to_measurement(raw, profile)
    assert m.data.dtype == np.float32 and m.data.shape == rgb.shape
    np.testing.assert_array_equal(m.data, rgb.astype(np.float32))
    assert m.black_level_dn == 64.0
    assert (m.timestamp_ns, m.frame_id, m.exposure_us) == (123, 7, 5000.0)
    assert m.meta["gain_db"] == 1.5 and m.meta["device_timestamp_ns"] == 99
    np.testing.assert_allclose(m.signal(), rgb.astype(np.float32) - 64.0)


def test_mono_coded_mosaic_uses_profile_pattern(profile):
    rgb = _rgb(profile, 1)
    raw = RawFrame(mosaic_from_rgb(rgb, "RGGB"), 0, 0, pixel_format="Mono16")
    np.testing.assert_array_equal(to_measurement(raw, profile).data, rgb)


def test_rgb_and_rgba_frames_pass_through(profile):
    rgb = _rgb(profile, 2)
    rgba = np.concatenate([rgb, np.full(rgb.shape[:2] + (1,), 7, np.uint16)], axis=2)
    for data in (rgb, rgba):
        m = to_measurement(RawFrame(data, 0, 0, pixel_format="RGB16"), profile)
        np.testing.assert_array_equal(m.data, rgb)


def test_wrong_frame_size_is_a_clear_error(profile):
    raw = RawFrame(np.zeros((100, 100), np.uint16), 0, 0, pixel_format="BayerRG12")
    with pytest.raises(DeviceError, match="expects a 128×160 measurement"):
        to_measurement(raw, profile)


def test_odd_mosaic_is_a_clear_error(profile):
    raw = RawFrame(np.zeros((101, 100), np.uint16), 0, 3, pixel_format="BayerRG8")
    with pytest.raises(DeviceError, match="frame 3"):
        to_measurement(raw, profile)


def test_frame_gap_counter_counts_and_warns():
    c = FrameGapCounter(warn=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        missing = [c.update(i) for i in (1, 2, 5, 6, 9)]
    assert missing == [0, 0, 2, 0, 2]
    assert c.dropped == 4 and c.gaps == [(5, 2), (9, 2)] and c.frames == 5
    assert sum(issubclass(w.category, DroppedFramesWarning) for w in caught) == 2
    assert c.update(0) == 0 and c.dropped == 4  # restart: no drop counted


def test_create_camera_errors(profile):
    with pytest.raises(ProfileError, match="no 'camera' section"):
        create_camera(profile.model_copy(update={"camera": None}))
    cam_cfg = profile.camera.model_copy(update={"plugin": "no-such-camera"})
    with pytest.raises(PluginError, match="no-such-camera"):
        create_camera(profile.model_copy(update={"camera": cam_cfg}))


def test_bit_depth_check(profile):
    assert [pixel_format_bits(f) for f in ("BayerRG12", "BayerRG12p", "Mono8", "RGBa8")] == [
        12, 12, 8, 8]
    assert pixel_format_bits("Custom") is None
    assert bit_depth_problem("BayerRG12", profile) is None  # saturation 4095 DN fits 12 bit
    assert "at most 255 DN" in bit_depth_problem("BayerRG8", profile)
    assert bit_depth_problem("BayerRG32f", profile) is None


def test_open_camera_and_read_measurement_through_a_real_plugin(tmp_path, profile):
    from thintact_sdk.device.cameras import open_camera, read_measurement
    from thintact_sdk.formats.recording import RecordingWriter

    rgb = _rgb(profile, 9)
    RecordingWriter(tmp_path / "rec", profile).add(rgb, label="one")
    cam_cfg = profile.camera.model_copy(update={"plugin": "replay", "bayer_pattern": "none", "settings": {}})
    replay_profile = profile.model_copy(update={"camera": cam_cfg})
    with open_camera(replay_profile, settings={"path": str(tmp_path / "rec"),
                                               "rate": "fast"}) as cam:
        assert cam.is_open
        m = read_measurement(cam, replay_profile)
    np.testing.assert_array_equal(m.data, rgb)


def test_preallocated_output_is_filled(profile):
    rgb = _rgb(profile, 4)
    out = np.empty(rgb.shape, np.float32)
    for raw in (RawFrame(mosaic_from_rgb(rgb), 0, 0, "BayerRG16"), RawFrame(rgb, 0, 0, "RGB16")):
        out[...] = -1
        m = to_measurement(raw, profile, out=out)
        assert m.data is out
        np.testing.assert_array_equal(out, rgb)


def test_closing_the_virtual_camera_releases_what_rendering_held(profile):
    """The wizard calibrates after the capture with the camera closed: the virtual camera's
    simulator and cached signals (up to 256 MB) go with close(); opening again renders."""
    import gc
    import tracemalloc

    cam = create_camera(profile)
    cam.open()
    first = cam.read().data
    cam.close()
    signal_bytes = profile.sensor.rows * profile.sensor.cols * 3 * 8  # one cached float64 signal
    tracemalloc.start()
    try:
        cam.open()
        again = cam.read().data
        held = tracemalloc.get_traced_memory()[0]
        cam.close()
        gc.collect()
        released = held - tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert released >= signal_bytes, (released, signal_bytes)
    assert again.shape == first.shape and again.dtype == first.dtype
