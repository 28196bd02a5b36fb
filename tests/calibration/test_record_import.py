"""``thintact record import`` (issue 32 item 4): a folder of camera files → a recording with
roles, colour order, crop, tone curve, mono conversion and binning declared."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from independent_device import small_profile

from thintact_sdk.apps.cli.main import main
from thintact_sdk.formats.profiles import Profile, write_profile
from thintact_sdk.formats.recording import Recording


def _profile(tmp_path: Path, channels: tuple[str, ...], black: float = 0.0, sat: float = 65535.0) -> Path:
    p = small_profile(channels, rows=16, cols=20, scene=(8, 10), k=24)
    d = p.contract_dict()
    d["noise"] = {**d["noise"], "black_level_dn": black, "saturation_dn": sat}
    path = tmp_path / f"unit-{len(channels)}.yaml"
    write_profile(Profile.model_validate(d), path)
    return path


def _rgb(shape: tuple[int, int], seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(1000, 60000, (*shape, 3))


def _save(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB array with OpenCV (which takes BGR)."""
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))


def test_roles_binning_crop_colour_order_and_gamma(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    prof = _profile(tmp_path, ("R", "G", "B"))
    src = tmp_path / "cam"
    src.mkdir()
    lin = {name: _rgb((32 + 4, 40 + 6), s) for s, name in enumerate(["flat", "dark", "no-press", "press_1", "odd"])}
    g = 2.2
    for name, x in lin.items():  # 16-bit PNG, blue first (BGR), display-encoded with gamma 2.2
        enc = np.round(65535.0 * (x / 65535.0) ** (1 / g)).astype(np.uint16)
        _save(src / f"{name}.png", enc[..., ::-1])
    out = tmp_path / "rec"
    args = ["record", "import", str(src), "--profile", str(prof), "--out", str(out), "--colour-order", "BGR",
            "--linearize", "gamma=2.2", "--crop", "2,1,40,32", "--quiet"]
    assert main(args) == 2  # 'odd' has no role
    assert "odd.png: no role" in capsys.readouterr().err
    assert main([*args, "--role", "odd.png=press"]) == 0
    rec = Recording(out)
    labels = [f.label for f in rec.frames]
    assert labels == ["dark", "white", "reference", "odd", "press_1"]  # sorted by file name
    want = lin["press_1"][1:33, 2:42].reshape(16, 2, 20, 2, 3).mean(axis=(1, 3))
    got = rec.measurement(labels.index("press_1"))
    assert got.shape == (16, 20, 3) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=2e-3)  # 16-bit rounding of the encoded values
    assert float(np.min(rec.scene(labels.index("white")))) == 1.0
    assert float(np.max(rec.scene(labels.index("dark")))) == 0.0
    assert rec.scene(labels.index("reference")) is None
    manifest = json.loads((out / "manifest.json").read_text())
    assert {f["source"] for f in manifest["frames"]} == {f"{n}.png" for n in lin}


def test_shape_errors_name_the_file_and_the_sensor(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    prof = _profile(tmp_path, ("R", "G", "B"))
    src = tmp_path / "cam"
    src.mkdir()
    _save(src / "flat.png", _rgb((33, 40), 1).astype(np.uint16))
    assert main(["record", "import", str(src), "--profile", str(prof), "--out", str(tmp_path / "r"),
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "flat.png" in err and "33×40" in err and "16×20" in err and not (tmp_path / "r" / "manifest.json").exists()


def test_rgb_jpeg_and_video_of_a_mono_profile_are_converted(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    prof = _profile(tmp_path, ("mono",), sat=255.0)
    src = tmp_path / "cam"
    src.mkdir()
    flat = np.full((32, 40, 3), (200, 100, 50), np.uint8)
    _save(src / "flat.jpg", flat)
    writer = cv2.VideoWriter(str(src / "dark.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (40, 32))
    if not writer.isOpened():
        pytest.skip("OpenCV cannot write MJPEG here")
    for v in (10, 20, 30):
        writer.write(np.full((32, 40, 3), v, np.uint8))
    writer.release()
    out = tmp_path / "rec"
    assert main(["record", "import", str(src), "--profile", str(prof), "--out", str(out), "--linearize", "none",
                 "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "converted to mono" in text and "3 video frames averaged" in text
    rec = Recording(out)
    labels = [f.label for f in rec.frames]
    white = rec.measurement(labels.index("white"))
    assert white.shape == (16, 20, 1)
    assert abs(float(white.mean()) - (0.299 * 200 + 0.587 * 100 + 0.114 * 50)) < 3  # JPEG rounding
    dark = rec.measurement(labels.index("dark"))
    assert abs(float(dark.mean()) - 20.0) < 3 and rec.frames[labels.index("dark")].extra["frames"] == 3


def test_mapping_file_and_a_scene_role(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    prof = _profile(tmp_path, ("R", "G", "B"))
    src = tmp_path / "cam"
    src.mkdir()
    for name in ("a", "b"):
        _save(src / f"{name}.tif", _rgb((16, 20), 3).astype(np.uint16))
    scene = np.random.default_rng(0).uniform(0, 1, (8, 10, 3)).astype(np.float32)
    np.save(tmp_path / "shown.npy", scene)  # outside the folder: not taken for a camera frame
    out = tmp_path / "rec"
    (src / "roles.yaml").write_text("a.tif: white\nb.tif: flat-ish\n")
    assert main(["record", "import", str(src), "--profile", str(prof), "--out", str(out),
                 "--map", str(src / "roles.yaml"), "--quiet"]) == 2
    assert "unknown role 'flat-ish'" in capsys.readouterr().err
    (src / "roles.yaml").write_text(f"a.tif: white\nb.tif: scene={tmp_path / 'shown.npy'}\n")
    assert main(["record", "import", str(src), "--profile", str(prof), "--out", str(out),
                 "--map", str(src / "roles.yaml"), "--quiet"]) == 0
    rec = Recording(out)
    got = rec.scene([f.label for f in rec.frames].index("b"))
    assert got is not None
    np.testing.assert_allclose(got, scene)


def test_a_frame_that_is_not_finite_leaves_no_recording(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """The check ran when the frame was written, after the frames before it: the recording was
    left half-written (and rerunning needed --force)."""
    prof = _profile(tmp_path, ("R", "G", "B"))
    src = tmp_path / "cam"
    src.mkdir()
    np.save(src / "flat.npy", _rgb((32, 40), 1).astype(np.float32))
    bad = _rgb((32, 40), 2).astype(np.float32)
    bad[3, 4, 1] = np.nan
    np.save(src / "press_1.npy", bad)
    out = tmp_path / "r"
    assert main(["record", "import", str(src), "--profile", str(prof), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "press_1.npy: holds NaN or infinite values" in err and not (out / "manifest.json").exists()
