from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.profiles import read_profile_file
from thintact_sdk.formats.recording import Recording, RecordingWriter
from thintact_sdk.pixels.bayer import (
    bin_bayer,
    block_mean,
    mosaic_from_rgb,
    pattern_from_pixel_format,
    split_bayer,
)


def test_bin_bayer_rggb_by_hand() -> None:
    raw = np.array([[10, 20, 11, 21], [30, 40, 31, 41]], dtype=np.uint16)
    out = bin_bayer(raw, "RGGB")
    assert out.shape == (1, 2, 3) and out.dtype == np.float32
    np.testing.assert_array_equal(out[0, 0], [10, 25, 40])
    np.testing.assert_array_equal(out[0, 1], [11, 26, 41])
    np.testing.assert_array_equal(bin_bayer(raw, "BGGR")[0, 0], [40, 25, 10])
    np.testing.assert_array_equal(bin_bayer(raw, "GRBG")[0, 0], [20, 25, 30])


@settings(max_examples=30, deadline=None)
@given(st.sampled_from(["RGGB", "BGGR", "GRBG", "GBRG"]), st.integers(1, 6), st.integers(1, 6))
def test_mosaic_roundtrip(pattern: str, r: int, s: int) -> None:
    rgb = np.random.default_rng(r * 7 + s).integers(0, 4096, (r, s, 3)).astype(np.uint16)
    np.testing.assert_array_equal(bin_bayer(mosaic_from_rgb(rgb, pattern), pattern), rgb.astype(np.float32))


def test_bin_bayer_errors() -> None:
    with pytest.raises(ValueError, match="even"):
        bin_bayer(np.zeros((3, 4)), "RGGB")
    with pytest.raises(ValueError, match="unknown Bayer pattern"):
        bin_bayer(np.zeros((4, 4)), "XYZW")
    assert pattern_from_pixel_format("BayerRG12") == "RGGB"
    assert pattern_from_pixel_format("Mono8") is None


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
@pytest.mark.parametrize("block", [2, 3])
def test_one_pass_block_binning_is_binning_then_block_means(pattern: str, block: int) -> None:
    """``bin_bayer``/``split_bayer`` with ``block = b`` read the mosaic once and give what the
    2 × 2 binning followed by ``b × b`` block means gives: exactly for integer DN and b = 2
    (every partial sum is exact in float32), to float32 rounding otherwise."""
    rng = np.random.default_rng(block)
    raw = rng.integers(0, 4096, (12 * block, 10 * block)).astype(np.uint16)
    two_pass = block_mean(bin_bayer(raw, pattern), block)
    one_pass = bin_bayer(raw, pattern, block=block)
    assert one_pass.shape == (6, 5, 3) and one_pass.dtype == np.float32
    # by hand, the first pixel's R: the mean of the b² R sites of the top-left 2b × 2b cell
    r0, c0 = {"RGGB": (0, 0), "BGGR": (1, 1), "GRBG": (0, 1), "GBRG": (1, 0)}[pattern]
    assert one_pass[0, 0, 0] == pytest.approx(raw[r0:2 * block:2, c0:2 * block:2].mean(), rel=1e-6)
    if block == 2:
        np.testing.assert_array_equal(one_pass, two_pass)
    else:
        np.testing.assert_allclose(one_pass, two_pass, rtol=2e-7, atol=0)
    np.testing.assert_allclose(split_bayer(raw, pattern, block=block), block_mean(split_bayer(raw, pattern), block),
                               rtol=2e-7)
    floats = raw * np.float32(1.37)  # non-integer DN (a linearised frame)
    np.testing.assert_allclose(bin_bayer(floats, pattern, block=block), block_mean(bin_bayer(floats, pattern), block),
                               rtol=1e-6)
    out = np.zeros((6, 5, 3), np.float32)
    assert bin_bayer(raw, pattern, out, block=block) is out
    with pytest.raises(ValueError, match="multiples of"):
        bin_bayer(raw[:-2], pattern, block=block)


def test_recording_roundtrip_and_resume(tmp_path: Path, golden_dir: Path) -> None:
    prof = read_profile_file(golden_dir / "mini" / "profile.json")
    rng = np.random.default_rng(0)
    scene = rng.random((50, 64, 3), dtype=np.float32)
    meas = rng.integers(0, 4096, (128, 160, 3)).astype(np.uint16)
    w = RecordingWriter(tmp_path / "rec", prof)
    w.add(meas, scene, label="white", frame_id=7)
    w.add(meas + 1, None, label="touch")
    # a second writer resumes: existing frames are kept
    w2 = RecordingWriter(tmp_path / "rec", prof)
    assert w2.has_label("white") and w2.has_label("touch")
    w2.add(meas + 2, scene, label="third")
    rec = Recording(tmp_path / "rec")
    assert len(rec) == 3
    np.testing.assert_array_equal(rec.measurement(0), meas)
    assert rec.measurement(0).dtype == np.uint16
    np.testing.assert_array_equal(rec.scene(0), scene)
    assert rec.scene(1) is None
    assert rec.frames[0].extra["frame_id"] == 7
    manifest = json.loads((tmp_path / "rec" / "manifest.json").read_text())
    assert manifest["format"] == "thintact-recording/1"
    assert manifest["frames"][1] == {"measurement": "measurements/001_touch.npy", "label": "touch"}


def test_truncated_recording_is_a_clear_error(tmp_path: Path, golden_dir: Path) -> None:
    prof = read_profile_file(golden_dir / "mini" / "profile.json")
    w = RecordingWriter(tmp_path / "rec", prof)
    w.add(np.zeros((128, 160, 3), np.uint16), label="a")
    f = tmp_path / "rec" / "measurements" / "000_a.npy"
    f.write_bytes(f.read_bytes()[:200])
    with pytest.raises(RecordingError, match="truncated"):
        Recording(tmp_path / "rec").measurement(0)
    (tmp_path / "rec" / "manifest.json").write_text("{")
    with pytest.raises(RecordingError, match="invalid JSON"):
        Recording(tmp_path / "rec")


def test_png_scene_and_measurement(tmp_path: Path, golden_dir: Path) -> None:
    import cv2

    prof = read_profile_file(golden_dir / "mini" / "profile.json")
    root = tmp_path / "rec"
    (root / "scenes").mkdir(parents=True)
    (root / "measurements").mkdir()
    (root / "profile.json").write_text((golden_dir / "mini" / "profile.json").read_text())
    scene8 = np.zeros((50, 64, 3), np.uint8)
    scene8[..., 0] = 255  # red in RGB
    cv2.imwrite(str(root / "scenes" / "s.png"), scene8[..., ::-1])
    meas16 = np.full((128, 160, 3), 1000, np.uint16)
    meas16[..., 2] = 3000
    cv2.imwrite(str(root / "measurements" / "m.png"), meas16[..., ::-1])
    (root / "manifest.json").write_text(json.dumps({
        "format": "thintact-recording/1", "profile": "profile.json",
        "frames": [{"scene": "scenes/s.png", "measurement": "measurements/m.png"}]}))
    rec = Recording(root, profile=prof)
    s = rec.scene(0)
    assert s.dtype == np.float32 and s[0, 0, 0] == 1.0 and s[0, 0, 1] == 0.0
    m = rec.measurement(0)
    assert m.dtype == np.uint16 and m[0, 0, 2] == 3000 and m[0, 0, 0] == 1000
