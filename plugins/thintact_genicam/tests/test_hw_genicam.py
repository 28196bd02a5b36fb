"""genicam camera against the viky.cti virtual GenTL producer shipped with the genicam wheel."""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
from thintact_genicam import GenICamSettingWarning
from thintact_genicam.producers import list_devices, viky_producer

from thintact_sdk.device.cameras import create_camera, to_measurement
from thintact_sdk.errors import (
    DeviceError,
    DeviceLostError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    ProfileError,
    UnsupportedFeatureError,
)
from thintact_sdk.formats.profiles import load_profile

VIKY = viky_producer()
pytestmark = pytest.mark.skipif(VIKY is None, reason="genicam wheel without viky.cti")

MONO = {"Width": 320, "Height": 256, "PixelFormat": "Mono8", "AcquisitionFrameRate": 100.0}


def _profile(pattern="RGGB", bits=8, **settings):
    """virtual-mini geometry; an 8-bit noise model like viky's frames unless ``bits`` says."""
    base = load_profile("virtual-mini")
    cam = {"plugin": "genicam", "bayer_pattern": pattern,
           "settings": {"cti": str(VIKY), **settings}}
    noise = base.noise.model_copy(update={"black_level_dn": 4.0,
                                          "saturation_dn": float(2**bits - 1)})
    return base.model_copy(update={"camera": type(base.camera).model_validate(cam),
                                   "noise": noise})


def test_viky_lists_its_devices():
    devices = list_devices(VIKY)
    assert [d["serial"] for d in devices] == ["0", "1", "2"]
    assert all(d["model"] == "Viky" for d in devices)


def test_settings_frames_and_missing_features():
    prof = _profile(bits=12, **MONO, ExposureTime=5000.0, gain_db=2.0)
    cam = create_camera(prof)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cam.open()
    try:
        msgs = [str(w.message) for w in caught if w.category is GenICamSettingWarning]
        assert any("ExposureTime" in m for m in msgs) and any("Gain" in m for m in msgs)
        # viky is 8-bit, this profile's noise model saturates at 4095 DN
        assert any("Mono8 gives at most 255 DN" in m for m in msgs)
        caps = cam.capabilities()
        assert caps.missing == ["ExposureTime", "Gain"]
        assert (caps.width, caps.height, caps.pixel_format) == (320, 256, "Mono8")
        assert set(caps.pixel_formats) == {"Mono8", "RGBa8"}
        assert caps.fps == pytest.approx(100.0)
        assert caps.exposure_range_us is None and caps.gain_range_db is None
        assert caps.fps_range.min == 1.0 and caps.fps_range.max == 200.0
        frames = [cam.read(timeout_s=2.0) for _ in range(3)]
        with pytest.raises(UnsupportedFeatureError, match="ExposureTime"):
            cam.set_exposure_us(1000.0)
    finally:
        cam.close()
    ids = [f.frame_id for f in frames]
    assert ids == sorted(ids) and len(set(ids)) == 3
    for f in frames:
        assert f.data.shape == (256, 320) and f.data.dtype == np.uint8
        assert f.pixel_format == "Mono8"
        m = to_measurement(f, prof)
        assert m.data.shape == (128, 160, 3) and m.black_level_dn == 4.0
    assert frames[1].timestamp_ns > frames[0].timestamp_ns
    cam.close()  # twice is fine


def test_rgba_frames_pass_through():
    prof = _profile("none", Width=160, Height=128, PixelFormat="RGBa8")
    with create_camera(prof) as cam:
        raw = cam.read()
    assert raw.data.shape == (128, 160, 4)
    m = to_measurement(raw, prof)
    np.testing.assert_array_equal(m.data, raw.data[..., :3].astype(np.float32))


def test_strict_unsupported_format_and_range_errors():
    with pytest.raises(UnsupportedFeatureError, match="ExposureTime .*strict"):
        create_camera(_profile(**MONO, ExposureTime=1000.0, strict=True)).open()
    with pytest.raises(UnsupportedFeatureError, match="BayerRG12.*offers"):
        create_camera(_profile(**{**MONO, "PixelFormat": "BayerRG12"})).open()
    with pytest.raises(DeviceError, match=r"AcquisitionFrameRate 1000.0 Hz is outside"):
        create_camera(_profile(**{**MONO, "AcquisitionFrameRate": 1000.0})).open()
    with pytest.raises(ProfileError, match="unknown genicam camera setting"):
        create_camera(_profile(Exposure=3))


def test_device_selection_errors(tmp_path):
    with pytest.raises(DeviceNotFoundError, match="offers 3 device"):
        create_camera(_profile(**MONO, index=7)).open()
    with pytest.raises(DeviceNotFoundError, match="cannot open camera"):
        create_camera(_profile(**MONO, serial="nope")).open()
    with pytest.raises(DeviceNotFoundError, match="producer .* not found"):
        create_camera(_profile(cti=str(tmp_path / "vendor.cti")))
    with create_camera(_profile(**MONO, serial="2")) as cam:
        assert cam.read().data.shape == (256, 320)


def test_dropped_frames_are_counted():
    prof = _profile(**{**MONO, "AcquisitionFrameRate": 200.0}, num_buffers=1)
    with create_camera(prof) as cam:
        frames = []
        for _ in range(4):
            frames.append(cam.read())
            time.sleep(0.1)
        dropped = cam.dropped_frames
    assert dropped > 0
    ids = [f.frame_id for f in frames]
    assert dropped == ids[-1] - ids[0] + 1 - len(ids)
    assert sum(f.meta.get("dropped_before", 0) for f in frames) == dropped


def test_read_timeout_is_bounded():
    with create_camera(_profile(**{**MONO, "AcquisitionFrameRate": 1.0})) as cam:
        cam.read(timeout_s=3.0)
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeoutError, match="no frame"):
            cam.read(timeout_s=0.2)
        assert time.monotonic() - t0 < 1.0


def _pull_the_plug(cam):
    """The producer and its device vanish underneath the stream (the acquisition running).

    Done between two reads of the reading thread: harvesters is not thread-safe, and a
    reset from a timer thread raced the camera's own release of the lost device (both
    stopped the same acquirer; one failed half-way, AttributeError inside harvesters), which
    left the process's one GenTL system open so that no later test could find the camera."""
    cam._harvester.reset()


def test_device_lost_mid_stream_is_a_clear_error():
    cam = create_camera(_profile(**MONO))
    cam.open()
    for _ in range(3):
        cam.read(timeout_s=1.0)
    _pull_the_plug(cam)
    t0 = time.monotonic()
    with pytest.raises(DeviceLostError, match="lost mid-stream"):
        for _ in range(1000):
            cam.read(timeout_s=1.0)
    assert time.monotonic() - t0 < 3.0
    with pytest.raises(DeviceError, match="not open"):
        cam.read()
    cam.close()


def test_device_lost_then_reconnected():
    cam = create_camera(_profile(**MONO, reconnect_s=5.0))
    cam.open()
    try:
        frames = [cam.read(timeout_s=1.0) for _ in range(3)]
        _pull_the_plug(cam)
        t0 = time.monotonic()
        while cam.reconnects == 0 and time.monotonic() - t0 < 5.0:
            frames.append(cam.read(timeout_s=1.0))
        assert cam.reconnects == 1
        assert frames[-1].meta.get("reconnected") is True
        assert cam.read().data.shape == (256, 320)
    finally:
        cam.close()


def test_vendor_features_are_written_or_reported():
    prof = _profile(**MONO, features={"BouncingBallSize": 30, "AcquisitionMode": "Continuous",
                                      "AspectRatio": 2.0, "LaserPower": 3})
    cam = create_camera(prof)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cam.open()
    try:
        # AcquisitionMode is read-only but already Continuous; AspectRatio is read-only
        assert cam.capabilities().missing == ["AspectRatio", "LaserPower"]
        msgs = " | ".join(str(w.message) for w in caught)
        assert "LaserPower cannot be honoured: the device has no such feature" in msgs
        assert "AspectRatio cannot be honoured: the device does not allow writing" in msgs
        nm = cam._node_map()
        assert nm.BouncingBallSize.value == 30 and nm.AcquisitionMode.value == "Continuous"
    finally:
        cam.close()
    with pytest.raises(DeviceError, match="BouncingBallSize 500 .* outside the device's range"):
        create_camera(_profile(**MONO, features={"BouncingBallSize": 500})).open()


def test_opening_twice_restarts_cleanly():
    cam = create_camera(_profile(**MONO))
    cam.open()
    try:
        cam.read()
        cam.open()
        assert cam.read().data.shape == (256, 320) and cam.dropped_frames == 0
    finally:
        cam.close()
