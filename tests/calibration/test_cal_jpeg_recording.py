"""8-bit JPEG recordings of a camera with a tone curve (sRGB), end to end: the recording reader
undoes the profile's declared ``sensor.tone_curve``; ``thintact calibrate --from-recording`` and
``thintact reconstruct`` work on it; the same JPEGs read as if linear fail. Also MJPEG video
frames (``video_frame``) and the reader's refusals."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from independent_device import small_profile
from sim_cli_device import simulate_recording

from thintact_sdk.apps.cli.main import main
from thintact_sdk.calibration.validation import score
from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.profiles import Profile, profile_from_dict
from thintact_sdk.formats.recording import Recording
from thintact_sdk.pixels.tone_curve import encode


def jpeg_camera_profile() -> Profile:
    """The small independent device behind an 8-bit sRGB-encoding camera (black 4 DN)."""
    d = small_profile().contract_dict()
    d["noise"] = {"black_level_dn": 4.0, "read_noise_dn": 0.6, "electrons_per_dn": 40.0,
                  "saturation_dn": 255.0}
    d["sensor"]["tone_curve"] = {"kind": "srgb"}
    return profile_from_dict(d)


def _encode_8bit(profile: Profile) -> object:
    return lambda dn: np.clip(np.rint(encode(dn, profile)), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def jpeg_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("jpeg")
    prof = jpeg_camera_profile()
    simulate_recording(root / "rec", prof, encode=_encode_8bit(prof), file_format="jpg")  # type: ignore[arg-type]
    return root / "rec"


def _gel_psnrs(rec_dir: Path, est_dir: Path) -> list[float]:
    rec = Recording(rec_dir)
    out = []
    for i, fr in enumerate(rec.frames):
        if fr.label and fr.label.startswith("val_gelsight"):
            truth = rec.scene(i)
            assert truth is not None
            out.append(score("gel", np.load(est_dir / f"{Path(fr.measurement).stem}.npy"), truth).psnr_db)
    return out


def test_jpeg_frames_are_read_as_linear_dn(jpeg_recording: Path) -> None:
    rec = Recording(jpeg_recording)
    white = next(i for i, f in enumerate(rec.frames) if f.label == "white")
    assert rec.frames[white].measurement.endswith(".jpg") and rec.tone_mapped(white)
    lin = rec.measurement(white)
    assert lin.dtype == np.float32 and lin.shape == (64, 80, 3)
    codes = np.asarray(Recording(jpeg_recording, profile=_without_curve(rec.profile)).measurement(white))
    assert codes.dtype == np.uint8
    # sRGB lifts mid-tones: the encoded codes sit far above the linear DN there
    mid = (lin > 40) & (lin < 120)
    assert mid.sum() > 100 and float(np.median(codes[mid] - lin[mid])) > 30.0


def _without_curve(profile: Profile) -> Profile:
    d = profile.contract_dict()
    del d["sensor"]["tone_curve"]
    return profile_from_dict(d)


def test_calibrate_and_reconstruct_a_jpeg_recording(jpeg_recording: Path, tmp_path: Path) -> None:
    rc = main(["calibrate", "--from-recording", str(jpeg_recording), "--out", str(tmp_path / "cal"),
               "--filter-steps", "5", "--no-progress"])
    assert rc == 0, "a healthy 8-bit JPEG unit must pass its own validation"
    assert main(["reconstruct", str(jpeg_recording), "--calibration", str(tmp_path / "cal"),
                 "--out", str(tmp_path / "est"), "--no-progress"]) == 0
    good = _gel_psnrs(jpeg_recording, tmp_path / "est")
    assert min(good) > 20.0, good  # measured 22.1-22.5 dB (t2s-closed-form chosen)


@pytest.mark.slow
def test_the_same_jpegs_without_the_curve_fail(jpeg_recording: Path, tmp_path: Path) -> None:
    """With no declared curve the JPEG codes are decoded as if linear: the unit fails."""
    good = [22.1]  # the lowest gel-scene PSNR of the test above
    blind = tmp_path / "blind"
    shutil.copytree(jpeg_recording, blind)
    pj = json.loads((blind / "profile.json").read_text())
    del pj["sensor"]["tone_curve"]
    (blind / "profile.json").write_text(json.dumps(pj))
    assert main(["calibrate", "--from-recording", str(blind), "--out", str(tmp_path / "cal_blind"),
                 "--filter-steps", "5", "--no-progress"]) == 1
    assert main(["reconstruct", str(blind), "--calibration", str(tmp_path / "cal_blind"),
                 "--out", str(tmp_path / "est_blind"), "--no-progress"]) == 0
    bad = _gel_psnrs(blind, tmp_path / "est_blind")
    assert max(bad) < min(good) - 10.0, (good, bad)  # measured ~7 dB


def test_mjpeg_video_frames_match_the_jpeg_frames(jpeg_recording: Path, tmp_path: Path) -> None:
    import cv2

    rec = Recording(jpeg_recording)
    picks = [0, 1, len(rec) - 1]
    root = tmp_path / "video"
    shutil.copytree(jpeg_recording, root)
    writer = cv2.VideoWriter(str(root / "measurements" / "run.avi"), cv2.VideoWriter.fourcc(*"MJPG"),
                             30.0, (80, 64), True)
    for i in picks:
        img = cv2.imread(str(jpeg_recording / rec.frames[i].measurement))
        assert img is not None
        writer.write(img)
    writer.release()
    manifest = json.loads((root / "manifest.json").read_text())
    manifest["frames"] = [{**manifest["frames"][i], "measurement": "measurements/run.avi", "video_frame": k}
                          for k, i in enumerate(picks)]
    (root / "manifest.json").write_text(json.dumps(manifest))
    vid = Recording(root)
    for k, i in enumerate(picks):
        assert vid.tone_mapped(k)
        a, b = vid.measurement(k), rec.measurement(i)
        assert a.dtype == np.float32 and a.shape == b.shape
        assert float(np.mean(np.abs(a - b))) < 3.0  # re-encoded (4:2:0 chroma): a few DN
    manifest["frames"][0].pop("video_frame")
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(RecordingError, match="frame 0: .*video.*'video_frame'"):
        Recording(root)
    manifest["frames"][0]["video_frame"] = 9
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(RecordingError, match="video_frame 9 but the video holds 3"):
        Recording(root).measurement(0)


def test_the_reader_refuses_what_it_cannot_linearise(jpeg_recording: Path, tmp_path: Path) -> None:
    root = tmp_path / "r"
    shutil.copytree(jpeg_recording, root)
    manifest = json.loads((root / "manifest.json").read_text())
    first = manifest["frames"][0]
    first["tone_mapped"] = "yes"
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(RecordingError, match="frame 0: 'tone_mapped' must be true or false"):
        Recording(root)
    first["tone_mapped"] = True
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(RecordingError, match="tone_mapped: true.*declares no sensor.tone_curve"):
        Recording(root, profile=_without_curve(jpeg_camera_profile())).measurement(0)
    first["scene"] = first["measurement"]  # a JPEG scene
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(RecordingError, match="scene must be lossless"):
        Recording(root).scene(0)
