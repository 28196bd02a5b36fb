"""A one-channel (monochrome) device end to end, as a new user runs it: profile →
``thintact simulate`` → recording → ``thintact calibrate --from-recording`` → every decoder
through ``thintact reconstruct``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from independent_device import small_profile
from sim_cli_device import simulate_recording

from thintact_sdk.apps.cli.main import main
from thintact_sdk.calibration.validation import score

# every decoder for a mask device (``identity`` is the lens-based sensors' camera image);
# PSNR floors ~2 dB under what each reaches on the gel scenes here (23.3-23.8, 34.5-35.5,
# 24.9-25.1, 19.0-19.6 dB; flatcam drops the open term by design, 5 filter steps only)
DECODERS = {"thintact-noniterative": 21.0, "t2s-closed-form": 32.0, "t2s-iterative": 22.0, "flatcam": 17.0}


@pytest.fixture(scope="module")
def mono_calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("mono")
    simulate_recording(root / "rec", small_profile(("mono",)))
    rc = main(["calibrate", "--from-recording", str(root / "rec"), "--out", str(root / "cal"),
               "--filter-steps", "5", "--no-progress"])
    assert rc == 0, "a healthy monochrome unit must pass its own validation"
    return root / "rec", root / "cal"


def test_monochrome_bundle_is_one_channel(mono_calibrated: tuple[Path, Path]) -> None:
    from thintact_sdk.reconstruction.bundle import CalibrationBundle

    _, cal = mono_calibrated
    bundle = CalibrationBundle.load(cal)
    assert bundle.system_matrices.channels == 1
    assert bundle.filter is not None and bundle.filter.channels == 1
    assert json.loads((cal / "calibration.json").read_text())["source"] == "recording"


@pytest.mark.parametrize("decoder", sorted(DECODERS))
def test_every_decoder_reconstructs_the_monochrome_recording(
        mono_calibrated: tuple[Path, Path], tmp_path: Path, decoder: str) -> None:
    from thintact_sdk.formats.recording import Recording

    rec_dir, cal = mono_calibrated
    args = ["reconstruct", str(rec_dir), "--calibration", str(cal), "--out", str(tmp_path / "est"),
            "--decoder", decoder, "--no-progress"]
    assert main(args) == 0
    rec = Recording(rec_dir)
    psnrs = []
    for i, fr in enumerate(rec.frames):
        if fr.label and fr.label.startswith("val_gelsight"):
            est = np.load(tmp_path / "est" / f"{Path(fr.measurement).stem}.npy")
            assert est.shape == (24, 32, 1) and np.isfinite(est).all()
            truth = rec.scene(i)
            assert truth is not None
            psnrs.append(score("gel", est, truth).psnr_db)
    assert len(psnrs) == 3 and min(psnrs) > DECODERS[decoder], psnrs


def test_the_capture_path_passes_monochrome_frames_through() -> None:
    from thintact_sdk.device.cameras import open_camera, to_measurement
    from thintact_sdk.errors import DeviceError
    from thintact_sdk.formats.profiles import profile_from_dict
    from thintact_sdk.frames import RawFrame

    d = small_profile(("mono",)).contract_dict()
    d["camera"] = {"plugin": "virtual", "settings": {"noise": False}}
    prof = profile_from_dict(d)
    with open_camera(prof) as cam:
        raw = cam.read()
    assert raw.data.shape == (64, 80) and raw.pixel_format == "Mono12"
    m = to_measurement(raw, prof)
    assert m.data.shape == (64, 80, 1)
    np.testing.assert_array_equal(m.data[..., 0], raw.data)  # no Bayer binning
    rgb = RawFrame(data=np.zeros((64, 80, 3), np.uint16), timestamp_ns=0, frame_id=1, pixel_format="RGB8",
                   exposure_us=None, gain_db=None)
    with pytest.raises(DeviceError, match="monochrome sensor delivers 2-D frames"):
        to_measurement(rgb, prof)


def test_score_psnr_is_scores_psnr_without_the_ssim() -> None:
    # the τ and decoder searches score thousands of estimates by PSNR alone: the same figure
    from thintact_sdk.calibration.validation import score, score_psnr

    rng = np.random.default_rng(0)
    truth = rng.random((12, 16, 3)).astype(np.float32)
    for estimate in (truth + rng.normal(0, 0.2, truth.shape),  # leaves [0, 1]: clipped
                     (truth.mean(axis=2) + rng.normal(0, 0.05, truth.shape[:2]))[..., None],  # one channel
                     truth.mean(axis=2)):  # a monochrome estimate without a channel axis
        assert score_psnr(estimate, truth) == score("x", estimate, truth).psnr_db
