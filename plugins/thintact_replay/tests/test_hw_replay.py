"""replay camera against recordings written by the core RecordingWriter."""

from __future__ import annotations

import time

import numpy as np
import pytest
from thintact_replay import EndOfRecording

from thintact_sdk.device.cameras import FrameGapCounter, create_camera, to_measurement
from thintact_sdk.errors import DeviceTimeoutError, ProfileError, RecordingError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.formats.raw_frames import save_raw_frame
from thintact_sdk.formats.recording import RecordingWriter
from thintact_sdk.frames import RawFrame
from thintact_sdk.pixels.bayer import mosaic_from_rgb


def _profile(path, pattern="RGGB", **settings):
    base = load_profile("virtual-mini")
    cam = {"plugin": "replay", "bayer_pattern": pattern, "settings": {"path": str(path), **settings}}
    return base.model_copy(update={"camera": type(base.camera).model_validate(cam)})


def _write(root, n=5, dtype=np.uint16, period_ns=50_000_000, ids=None, scenes=True, seed=0):
    prof = load_profile("virtual-mini")
    w = RecordingWriter(root, prof)
    rng = np.random.default_rng(seed)
    meas = []
    for i in range(n):
        m = rng.integers(64, 4000, size=(128, 160, 3))
        m = m.astype(dtype) if dtype == np.uint16 else (m + 0.5).astype(np.float32)
        scene = rng.random((50, 64, 3), dtype=np.float32) if scenes else None
        fid = ids[i] if ids else 100 + i
        w.add(m, scene=scene, label=f"f{i}", timestamp_ns=1_000_000 + i * period_ns,
              frame_id=fid, exposure_us=2500.0)
        meas.append(m)
    return meas


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
@pytest.mark.parametrize("pattern", ["RGGB", "GBRG", "none"])
def test_replay_bins_back_to_the_recording_exactly(tmp_path, dtype, pattern):
    meas = _write(tmp_path / "rec", dtype=dtype)
    prof = _profile(tmp_path / "rec", pattern, rate="fast")
    with create_camera(prof) as cam:
        raws = list(cam)
    assert len(raws) == 5
    for raw, m in zip(raws, meas, strict=True):
        got = to_measurement(raw, prof)
        assert got.data.dtype == np.float32
        np.testing.assert_array_equal(got.data, m.astype(np.float32))
        assert got.exposure_us == 2500.0
        assert raw.meta["scene"].shape == (50, 64, 3)
    assert [r.frame_id for r in raws] == [100, 101, 102, 103, 104]


def test_recorded_rate_and_speed(tmp_path):
    _write(tmp_path / "rec", n=5, period_ns=60_000_000, scenes=False)
    for speed, expected in ((1.0, 0.24), (3.0, 0.08)):
        with create_camera(_profile(tmp_path / "rec", speed=speed)) as cam:
            t0 = time.monotonic()
            stamps = [cam.read().timestamp_ns for _ in range(5)]
            elapsed = time.monotonic() - t0
        assert expected - 0.01 <= elapsed <= expected + 0.15
        assert stamps == sorted(stamps)


def test_end_of_recording_and_loop(tmp_path):
    _write(tmp_path / "rec", n=3, scenes=False)
    with create_camera(_profile(tmp_path / "rec", rate="fast")) as cam:
        for _ in range(3):
            cam.read()
        with pytest.raises(EndOfRecording, match="ended after 3 frames"):
            cam.read()
    with create_camera(_profile(tmp_path / "rec", rate="fast", loop=True)) as cam:
        ids = [cam.read().frame_id for _ in range(7)]
    assert ids == [100, 101, 102, 103, 104, 105, 106]
    gaps = FrameGapCounter()
    for i in ids:
        gaps.update(i)
    assert gaps.dropped == 0


def test_recorded_frame_gaps_are_replayed(tmp_path):
    _write(tmp_path / "rec", n=4, ids=[5, 6, 9, 10], scenes=False)
    gaps = FrameGapCounter()
    with create_camera(_profile(tmp_path / "rec", rate="fast")) as cam:
        for raw in cam:
            gaps.update(raw.frame_id)
    assert gaps.dropped == 2


def test_frame_due_after_timeout_is_a_timeout(tmp_path):
    _write(tmp_path / "rec", n=2, period_ns=2_000_000_000, scenes=False)
    with create_camera(_profile(tmp_path / "rec")) as cam:
        cam.read()
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeoutError, match="beyond the read timeout"):
            cam.read(timeout_s=0.1)
        assert time.monotonic() - t0 < 0.5


def test_kept_raw_mosaics_are_delivered_as_recorded(tmp_path):
    root = tmp_path / "rec"
    prof = load_profile("virtual-mini")
    w = RecordingWriter(root, prof)
    rgb = np.random.default_rng(3).integers(0, 4095, size=(128, 160, 3)).astype(np.uint16)
    raw = RawFrame(mosaic_from_rgb(rgb, "BGGR"), 0, 1, pixel_format="BayerBG12")
    raw.data[0, 0] += 1  # a real mosaic: the two greens differ (G site of BGGR at (0, 1))
    extra = save_raw_frame(root, 0, raw)
    w.add(to_measurement(raw, prof).data, label="x", frame_id=1, **extra)
    with create_camera(_profile(root, rate="fast")) as cam:
        got = cam.read()
    assert got.pixel_format == "BayerBG12"
    np.testing.assert_array_equal(got.data, raw.data)
    with create_camera(_profile(root, rate="fast", raw=False)) as cam:
        assert cam.read().pixel_format == "BayerRG32f"  # re-mosaicked float measurement


def test_truncated_and_missing_files_are_clear_errors(tmp_path):
    root = tmp_path / "rec"
    _write(root, n=4, scenes=False)
    victim = sorted((root / "measurements").iterdir())[2]
    victim.write_bytes(victim.read_bytes()[:1000])
    with pytest.raises(RecordingError, match=r"frame 2 .* truncated.*frames 0\.\.1 are intact"):
        create_camera(_profile(root)).open()
    victim.unlink()
    with pytest.raises(RecordingError, match="frame 2 .* missing"):
        create_camera(_profile(root)).open()


def test_missing_scene_is_found_at_open(tmp_path):
    root = tmp_path / "rec"
    _write(root, n=3)
    sorted((root / "scenes").iterdir())[1].unlink()
    with pytest.raises(RecordingError, match=r"frame 1 file scenes/.* is missing"):
        create_camera(_profile(root)).open()
    with create_camera(_profile(root, scenes=False, rate="fast")) as cam:
        assert len(list(cam)) == 3  # scenes not wanted: the recording plays


def test_bad_settings(tmp_path):
    with pytest.raises(ProfileError, match="settings.path"):
        create_camera(_profile(tmp_path).model_copy(
            update={"camera": load_profile("virtual-mini").camera.model_copy(
                update={"plugin": "replay", "settings": {}})}))
    with pytest.raises(RecordingError, match="no manifest.json"):
        create_camera(_profile(tmp_path / "nothing")).open()
    with pytest.raises(ProfileError, match="rate"):
        create_camera(_profile(tmp_path, rate="slowly"))


def test_capabilities_describe_the_recording(tmp_path):
    _write(tmp_path / "rec", n=5, period_ns=50_000_000, scenes=False)
    with create_camera(_profile(tmp_path / "rec", "BGGR")) as cam:
        caps = cam.capabilities()
        assert len(cam) == 5
    assert (caps.width, caps.height, caps.pixel_format) == (320, 256, "BayerBG16")
    assert caps.fps == pytest.approx(20.0)
    assert caps.missing == ["ExposureTime", "Gain"]


def test_png_measurements_replay_exactly(tmp_path):
    import json

    import cv2

    root = tmp_path / "rec"
    (root / "measurements").mkdir(parents=True)
    prof = load_profile("virtual-mini")
    RecordingWriter(root, prof)  # manifest + profile.json
    rng = np.random.default_rng(11)
    meas, frames = [], []
    for i in range(2):
        m = rng.integers(0, 65535, size=(128, 160, 3)).astype(np.uint16)
        cv2.imwrite(str(root / "measurements" / f"{i}.png"), m[..., ::-1])  # PNG stores BGR
        meas.append(m)
        frames.append({"measurement": f"measurements/{i}.png", "label": f"p{i}"})
    manifest = json.loads((root / "manifest.json").read_text())
    manifest["frames"] = frames
    (root / "manifest.json").write_text(json.dumps(manifest))
    p = _profile(root, rate="fast")
    with create_camera(p) as cam:
        got = [to_measurement(r, p).data for r in cam]
    assert len(got) == 2
    for g, m in zip(got, meas, strict=True):
        np.testing.assert_array_equal(g, m)
