"""DIGIT and GelSight Mini through the same API: real frames played through the UVC path,
identity imaging, their LUT, the same TactileFrame."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

import thintact_sdk as thintact
from thintact_sdk.errors import CalibrationError, DeviceNotFoundError, ProfileError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.frames import TactileFrame
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT

TEST_PRESSES = [3, 9, 15, 21, 27, 33]  # none of them is among the 8 the LUT was made from


@pytest.fixture(scope="module")
def taxim(shared_dir):
    with np.load(shared_dir / "data" / "taxim_gelsight_ball_small" / "dataPack_small.npz",
                 allow_pickle=True) as z:
        return {k: z[k] for k in ("f0", "imgs", "touch_center", "touch_radius")}


def _image_sequence(frames_rgb: list[np.ndarray], folder: Path, upscale: int = 1) -> str:
    """Write RGB uint8 frames as a lossless PNG sequence (BGR on disk), optionally upscaled
    by pixel repetition (the identity decoder's area average gives the frame back exactly)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, rgb in enumerate(frames_rgb):
        big = np.repeat(np.repeat(rgb, upscale, axis=0), upscale, axis=1)
        cv2.imwrite(str(folder / f"img_{i:04d}.png"), np.ascontiguousarray(big[..., ::-1]))
    return str(folder / "img_%04d.png")


def test_gelsight_mini_end_to_end_on_real_ball_presses(taxim, tmp_path):
    frames = [taxim["f0"]] + [taxim["imgs"][i] for i in TEST_PRESSES]
    # the Mini's 320x240 stream: the gel (these frames, as gs_sdk crops them) inside the
    # housing border the profile crops away (1/7 per side: 34 rows, 45 columns)
    stream = []
    for f in frames:
        s = np.full((240, 320, 3), 20, np.uint8)
        s[34:206, 45:275] = cv2.resize(f, (230, 172), interpolation=cv2.INTER_LINEAR)
        stream.append(s)
    device = _image_sequence(stream, tmp_path / "mini")
    with thintact.open("gelsight-mini", camera_settings={"device": device, "width": 320,
                                                           "height": 240}) as sensor:
        ref = sensor.read()
        presses = [sensor.read() for _ in TEST_PRESSES]
    assert isinstance(ref, TactileFrame) and not ref.contact
    # identity imaging of the cropped gel (up to resampling it twice)
    np.testing.assert_allclose(ref.image, taxim["f0"] / 255.0, atol=0.05)
    mm = 0.1245
    for i, frame in zip(TEST_PRESSES, presses, strict=True):
        assert frame.contact, f"press {i}"
        core = frame.depth_mm >= 0.5 * frame.depth_mm.max()
        rows, cols = np.nonzero(core)
        w = frame.depth_mm[core]
        row, col = float((w * rows).sum() / w.sum()), float((w * cols).sum() / w.sum())
        cx, cy = taxim["touch_center"][i]
        off = float(np.hypot(col - cx, row - cy))
        assert off < 4.0, f"press {i}: contact {off:.1f} px from the annotated centre"
        # a 2 mm ball whose contact circle has the annotated radius r: cap depth R - √(R² - r²)
        r_mm = min(float(taxim["touch_radius"][i]) * mm, 1.95)
        cap = 2.0 - np.sqrt(4.0 - r_mm**2)
        assert 0.3 * cap < float(frame.depth_mm.max()) < 2.0 * cap, f"press {i}"
        assert frame.force_n is not None and frame.force_n[2] > 0
        assert np.isnan(frame.force_n[:2]).all()  # a marker-free gel: shear unknown
    assert presses[0].frame_id == ref.frame_id + 1


def test_digit_opens_with_the_same_calls_on_its_real_background(shared_dir, tmp_path):
    bg = cv2.imread(str(shared_dir / "data" / "tacto_digit_background" / "bg_digit_240_320.jpg"))
    rgb = bg[..., ::-1].copy()
    assert rgb.shape == (320, 240, 3)  # portrait, as digit-interface's get_frame returns it
    # the device streams landscape; the profile transposes and flips it back to portrait
    device = _image_sequence([cv2.rotate(rgb, cv2.ROTATE_90_CLOCKWISE)] * 2, tmp_path / "digit")
    settings = {"device": device}
    # an image sequence has no LEDs: the profile's LED setting is reported, not dropped silently
    no_led = "does not accept setting led_intensity"
    with pytest.warns(UserWarning, match=no_led), \
            thintact.open("digit", camera_settings=settings) as sensor:
        with pytest.raises(CalibrationError, match="calibrate-tactile --profile digit"):
            sensor.read()
    # with a LUT (here the GelSight one: the background shows no colour change, so any LUT
    # gives zero depth) the DIGIT yields the same TactileFrame as every other sensor
    lut = PhotometricLUT.load(Path(thintact.__file__).parent / "data" / "gelsight"
                              / "gelsight-mini-lut.npz")
    with pytest.warns(UserWarning, match=no_led), \
            thintact.open("digit", camera_settings=settings, lut=lut) as sensor:
        frames = [sensor.read(), sensor.read()]
    expected = cv2.resize(rgb.astype(np.float32) / 255.0, (120, 160), interpolation=cv2.INTER_AREA)
    for f in frames:
        assert f.image.shape == (160, 120, 3)
        np.testing.assert_allclose(f.image, expected, atol=1e-5)
        assert not f.contact and float(f.depth_mm.max()) == 0.0
        np.testing.assert_array_equal(f.force_n, np.zeros(3))
        assert f.slip_ratio is None


def test_lens_profiles_and_their_errors():
    for name in ("digit", "gelsight-mini"):
        p = load_profile(name)
        assert p.decoder.plugin == "identity" and p.camera.plugin == "uvc"
        assert p.mask.K == 1 and p.mask.phi == [1]  # open aperture: no coded mask
    with pytest.raises(DeviceNotFoundError, match="no UVC camera 7"):
        thintact.open("digit", camera_settings={"device": 7})
    from thintact_sdk.reconstruction.decoders.identity import IdentityDecoder

    with pytest.raises(ProfileError, match="flip must be one of"):
        IdentityDecoder((4, 4), 255.0, flip="sideways")
    dec = IdentityDecoder((2, 2), 100.0, flip="horizontal")
    out = dec.decode(np.arange(12, dtype=np.float32).reshape(2, 2, 3) * 10)
    np.testing.assert_allclose(out[0, 0], [0.3, 0.4, 0.5])
