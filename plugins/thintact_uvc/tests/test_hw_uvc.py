"""uvc camera against files OpenCV itself wrote: lossless videos and image sequences."""

from __future__ import annotations

import os
import threading
import time
import warnings

import cv2
import numpy as np
import pytest
from thintact_uvc import EndOfVideo, UvcSettingWarning

from thintact_sdk.device.cameras import create_camera, to_measurement
from thintact_sdk.errors import (
    DeviceNotFoundError,
    DeviceTimeoutError,
    ProfileError,
    RecordingError,
    UnsupportedFeatureError,
)
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.pixels.bayer import mosaic_from_rgb

R, S = 128, 160


def _profile(pattern="RGGB", **settings):
    base = load_profile("virtual-mini")
    cam = {"plugin": "uvc", "bayer_pattern": pattern, "settings": settings}
    return base.model_copy(update={"camera": type(base.camera).model_validate(cam)})


def _measurements(n, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.integers(64, 4095, size=(R, S, 3)).astype(np.uint16) for _ in range(n)]


def _write_video(path, frames, fourcc="FFV1", fps=30.0):
    h, w = frames[0].shape[:2]
    if frames[0].dtype == np.uint16:
        params = [cv2.VIDEOWRITER_PROP_DEPTH, cv2.CV_16U, cv2.VIDEOWRITER_PROP_IS_COLOR, 0]
    else:
        params = [cv2.VIDEOWRITER_PROP_IS_COLOR, int(frames[0].ndim == 3)]
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter.fourcc(*fourcc), fps,
                             (w, h), params)
    assert writer.isOpened(), f"this OpenCV cannot write {fourcc} to {path.suffix}"
    for f in frames:
        writer.write(f)
    writer.release()


def test_16bit_bayer_ffv1_video_bins_back_exactly(tmp_path):
    meas = _measurements(4)
    _write_video(tmp_path / "raw.mkv", [mosaic_from_rgb(m, "GRBG") for m in meas])
    prof = _profile("GRBG", device=str(tmp_path / "raw.mkv"))
    with create_camera(prof) as cam:
        caps = cam.capabilities()
        assert (caps.width, caps.height) == (2 * S, 2 * R)
        raws = [cam.read() for _ in range(4)]
        with pytest.raises(EndOfVideo, match="ended after 4 frames"):
            cam.read()
        assert cam.capabilities().pixel_format == "Mono16"
    assert [r.frame_id for r in raws] == [0, 1, 2, 3]
    for raw, m in zip(raws, meas, strict=True):
        assert raw.pixel_format == "Mono16" and raw.data.dtype == np.uint16
        np.testing.assert_array_equal(to_measurement(raw, prof).data, m)


@pytest.mark.parametrize(("name", "fourcc"), [("rgb.mkv", "FFV1"), ("rgb.avi", "MPNG")])
def test_8bit_colour_video_is_rgb_passthrough(tmp_path, name, fourcc):
    rgb = [(m // 16).astype(np.uint8) for m in _measurements(3, seed=1)]
    _write_video(tmp_path / name, [f[..., ::-1] for f in rgb], fourcc=fourcc)  # OpenCV writes BGR
    prof = _profile("none", device=str(tmp_path / name))
    with create_camera(prof) as cam:
        for expected in rgb:
            raw = cam.read()
            assert raw.pixel_format == "RGB8"
            np.testing.assert_array_equal(to_measurement(raw, prof).data, expected)


def test_image_sequence_16bit_png_and_loop(tmp_path):
    meas = _measurements(3, seed=2)
    for i, m in enumerate(meas):
        cv2.imwrite(str(tmp_path / f"img_{i:04d}.png"), mosaic_from_rgb(m))
    prof = _profile(device="img_%04d.png", loop=True)
    prof._source = tmp_path / "profile.yaml"  # relative device paths resolve next to the profile
    with create_camera(prof) as cam:
        got = [to_measurement(cam.read(), prof).data for _ in range(7)]
    for i, g in enumerate(got):
        np.testing.assert_array_equal(g, meas[i % 3])


def test_files_report_device_settings_as_missing(tmp_path):
    _write_video(tmp_path / "v.mkv", [mosaic_from_rgb(m) for m in _measurements(1)])
    prof = _profile(device=str(tmp_path / "v.mkv"), width=640, exposure_us=1000, gain=2)
    cam = create_camera(prof)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cam.open()
    try:
        assert sorted(cam.capabilities().missing) == ["exposure_us", "gain", "width"]
        assert sum(w.category is UvcSettingWarning for w in caught) == 3
        with pytest.raises(UnsupportedFeatureError):
            cam.set_exposure_us(100.0)
    finally:
        cam.close()
    with pytest.raises(UnsupportedFeatureError, match="strict"):
        create_camera(_profile(device=str(tmp_path / "v.mkv"), gain=1, strict=True)).open()


def test_fps_paces_file_playback(tmp_path):
    _write_video(tmp_path / "v.mkv", [mosaic_from_rgb(m) for m in _measurements(4)])
    with create_camera(_profile(device=str(tmp_path / "v.mkv"), fps=20.0)) as cam:
        t0 = time.monotonic()
        for _ in range(4):
            cam.read()
        assert 0.14 <= time.monotonic() - t0 <= 0.4


def test_truncated_video_is_a_clear_error(tmp_path):
    path = tmp_path / "v.mkv"
    _write_video(path, [mosaic_from_rgb(m) for m in _measurements(6)])
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises((RecordingError, DeviceNotFoundError), match="truncated|cannot open"):
        with create_camera(_profile(device=str(path))) as cam:
            for _ in range(6):
                cam.read()


def test_stalled_stream_times_out_and_keeps_the_late_frame(tmp_path):
    src = tmp_path / "v.mkv"
    meas = _measurements(40, seed=4)
    _write_video(src, [mosaic_from_rgb(m) for m in meas])
    data = src.read_bytes()
    fifo = tmp_path / "live.mkv"
    os.mkfifo(fifo)
    release = threading.Event()

    def feeder():
        with open(fifo, "wb") as f:
            f.write(data[: len(data) // 2])
            f.flush()
            release.wait(10)
            f.write(data[len(data) // 2:])

    t = threading.Thread(target=feeder, daemon=True)
    t.start()
    prof = _profile(device=str(fifo), open_timeout_s=5)
    with create_camera(prof) as cam:
        got = []
        with pytest.raises(DeviceTimeoutError, match="no frame"):
            for _ in range(40):
                got.append(cam.read(timeout_s=0.5))
        assert 0 < len(got) < 40
        release.set()
        rest = []
        while True:
            try:
                rest.append(cam.read(timeout_s=5))
            except (EndOfVideo, RecordingError):
                break
    t.join(5)
    frames = got + rest
    assert [f.frame_id for f in frames] == list(range(len(frames)))
    for f, m in zip(frames, meas, strict=False):
        np.testing.assert_array_equal(to_measurement(f, prof).data, m)


def test_missing_devices_and_settings(tmp_path):
    with pytest.raises(DeviceNotFoundError, match="no UVC camera 7"):
        create_camera(_profile(device=7))
    with pytest.raises(DeviceNotFoundError, match="/dev/video42"):
        create_camera(_profile(device="/dev/video42"))
    with pytest.raises(DeviceNotFoundError, match="not found"):
        create_camera(_profile(device=str(tmp_path / "none.mkv")))
    with pytest.raises(DeviceNotFoundError, match="image sequence"):
        create_camera(_profile(device=str(tmp_path / "img_%04d.png")))
    with pytest.raises(ProfileError, match="settings.device"):
        create_camera(_profile())
    with pytest.raises(ProfileError, match="unknown uvc camera setting"):
        create_camera(_profile(device=0, exposure=3))


def test_opening_twice_restarts_the_file(tmp_path):
    meas = _measurements(2, seed=5)
    _write_video(tmp_path / "v.mkv", [mosaic_from_rgb(m) for m in meas])
    prof = _profile(device=str(tmp_path / "v.mkv"))
    cam = create_camera(prof)
    cam.open()
    try:
        cam.read()
        cam.open()
        raw = cam.read()
        assert raw.frame_id == 0
        np.testing.assert_array_equal(to_measurement(raw, prof).data, meas[0])
    finally:
        cam.close()


# -- lens sensors: frame geometry and DIGIT LED intensity (docs/lens-sensors.md) -------------
def _landscape_frames(n, seed=5):
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, size=(240, 320, 3), dtype=np.uint8) for _ in range(n)]


def _lens_profile(name, device, **overrides):
    base = load_profile(name)
    settings = {**base.camera.settings, "device": device, **overrides}
    cam = base.camera.model_copy(update={"settings": settings})
    return base.model_copy(update={"camera": cam})


def test_digit_stream_is_transposed_and_flipped_as_digit_interface_does(tmp_path):
    frames = _landscape_frames(2)  # QVGA landscape, as the DIGIT streams it
    _write_video(tmp_path / "digit.mkv", [f[..., ::-1] for f in frames])
    prof = _lens_profile("digit", str(tmp_path / "digit.mkv"), fps=0)
    cam = create_camera(prof)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cam.open()
    try:
        caps = cam.capabilities()
        assert (caps.height, caps.width) == (prof.sensor.rows, prof.sensor.cols) == (320, 240)
        assert caps.missing == ["led_intensity"]  # a file has no LED
        assert any("led_intensity" in str(w.message) for w in caught)
        for f in frames:
            raw = cam.read()
            # digit-interface Digit.get_frame: cv2.transpose, then cv2.flip(frame, 0)
            want = cv2.flip(cv2.transpose(f), 0)
            np.testing.assert_array_equal(raw.data, want)
            np.testing.assert_array_equal(raw.data, cv2.rotate(f, cv2.ROTATE_90_COUNTERCLOCKWISE))
            assert to_measurement(raw, prof).data.shape == (320, 240, 3)
    finally:
        cam.close()


def test_gelsight_mini_crop_removes_a_seventh_of_each_side_as_gs_sdk_does(tmp_path):
    frames = _landscape_frames(1, seed=6)
    _write_video(tmp_path / "mini.mkv", [f[..., ::-1] for f in frames])
    prof = _lens_profile("gelsight-mini", str(tmp_path / "mini.mkv"))
    with create_camera(prof) as cam:
        caps = cam.capabilities()
        raw = cam.read()
    f = frames[0]
    bx, by = int(f.shape[0] * (1 / 7)), int(np.floor(f.shape[1] * (1 / 7)))  # gs_sdk resize_crop
    np.testing.assert_array_equal(raw.data, f[bx:f.shape[0] - bx, by:f.shape[1] - by])
    assert raw.data.shape[:2] == (caps.height, caps.width) == (172, 230)
    assert (prof.sensor.rows, prof.sensor.cols) == (172, 230)
    # the cropped field is the gel the scene covers: same mm either way
    assert prof.sensor.cols * prof.sensor.pixel_pitch_um == pytest.approx(
        prof.scene.cols * prof.scene.pixel_pitch_um, rel=1e-5)


@pytest.mark.parametrize("rotate", [90, 180, 270])
def test_rotate_crop_and_flip_settings(tmp_path, rotate):
    frames = _landscape_frames(1, seed=7)
    _write_video(tmp_path / "v.mkv", [f[..., ::-1] for f in frames])
    crop = {"top": 10, "bottom": 0.25, "left": "1/8", "right": 0}
    prof = _profile("none", device=str(tmp_path / "v.mkv"), crop=crop, flip="horizontal",
                    rotate=rotate)
    with create_camera(prof) as cam:
        caps = cam.capabilities()
        raw = cam.read()
    f = frames[0][10:240 - 60, 40:][:, ::-1]
    code = {90: cv2.ROTATE_90_COUNTERCLOCKWISE, 180: cv2.ROTATE_180,
            270: cv2.ROTATE_90_CLOCKWISE}[rotate]
    want = cv2.rotate(np.ascontiguousarray(f), code)
    np.testing.assert_array_equal(raw.data, want)
    assert (caps.height, caps.width) == want.shape[:2]


@pytest.mark.parametrize(("settings", "match"), [
    ({"crop": {"top": 0.5}}, r"crop.top: fraction 0.5 must be in \[0, 0.5\)"),
    ({"crop": {"left": "a/b"}}, r"crop.left: 'a/b' is neither pixels"),
    ({"crop": {"top": -3}}, r"crop.top: -3 pixels is negative"),
    ({"crop": {"top": 200, "bottom": 40}}, r"leave nothing of a 240×320 frame"),
    ({"rotate": 45}, r"camera.settings.rotate"),
    ({"flip": "sideways"}, r"camera.settings.flip"),
    ({"crop": {"middle": 3}}, r"camera.settings.crop.middle"),
    ({"led_intensity": 0}, r"camera.settings.led_intensity"),
])
def test_bad_geometry_settings_name_the_key(tmp_path, settings, match):
    from thintact_sdk.errors import CameraSettingsError

    _write_video(tmp_path / "v.mkv", [f[..., ::-1] for f in _landscape_frames(1)])
    with pytest.raises(CameraSettingsError, match=match):
        with create_camera(_profile("none", device=str(tmp_path / "v.mkv"), **settings)) as cam:
            cam.read()


def test_led_intensity_is_the_uvc_zoom_control_on_live_devices():
    from thintact_uvc.camera import UvcCamera

    class FakeCapture:
        def __init__(self):
            self.props = {}

        def set(self, prop, value):
            self.props[prop] = value
            return True

        def get(self, prop):
            return self.props.get(prop, 0.0)

    cam = UvcCamera.__new__(UvcCamera)
    cam.settings, cam.strict, cam._missing = {"led_intensity": 128}, False, []
    cam.source = type("S", (), {"is_live": True, "label": "/dev/video0"})()
    cam._cap = FakeCapture()
    cam._exposure_us = None
    cam._apply_settings()
    assert cam._cap.props[cv2.CAP_PROP_ZOOM] == 128.0 and cam._missing == []
