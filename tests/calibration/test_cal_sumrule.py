"""The white frame as the sum of the slits: dark level without a dark frame, hidden gains."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from cal_testkit import channel, synthetic_matrices, synthetic_profile, write_slit_recording

from thintact_sdk.calibration.collect import collect_slits
from thintact_sdk.calibration.gauge import operator_error
from thintact_sdk.calibration.pipeline import CalibrationOptions, solve_matrices
from thintact_sdk.formats.recording import Recording
from thintact_sdk.simulation.scenes import make_scene


def _errors(rec: Recording, sm_true, gains: str = "auto") -> tuple[list[float], object]:  # type: ignore[no-untyped-def]
    coll = collect_slits(rec, frame_gains=gains)
    sm, _ = solve_matrices(coll, CalibrationOptions(), rec.profile)
    return [operator_error(channel(sm, c), channel(sm_true, c)) for c in range(3)], coll


def test_dark_level_is_measured_without_a_dark_frame(tmp_path: Path) -> None:
    prof = synthetic_profile()
    sm_true = synthetic_matrices()
    yy, xx = np.mgrid[0:64, 0:80]
    offset = (6.0 + 4.0 * xx / 80 + 2.0 * yy / 64)[..., None]  # black shift + smooth stray light
    write_slit_recording(tmp_path / "r", prof, sm_true, None, [make_scene("white", 24, 32)], dark=False,
                         offset_dn=offset)
    errs, coll = _errors(Recording(tmp_path / "r"), sm_true, "off")
    assert coll.dark_source.startswith("measured from the white frame")  # type: ignore[attr-defined]
    want = prof.noise.black_level_dn + offset[..., 0]
    assert np.abs(coll.dark_dn[..., 1] - want).max() < 0.5  # DN rounding of 25 frames  # type: ignore[attr-defined]
    assert max(errs) < 1e-2


def test_hidden_exposure_differences_are_corrected_from_the_white_frame(tmp_path: Path) -> None:
    prof = synthetic_profile()
    sm_true = synthetic_matrices()
    rng = np.random.default_rng(5)
    hidden = {f"f{i}": float(1.0 + 0.1 * rng.uniform(-1, 1)) for i in range(1, 57)}
    write_slit_recording(tmp_path / "g", prof, sm_true, None, [make_scene("white", 24, 32)], hidden_gain=hidden)
    rec = Recording(tmp_path / "g")
    off, _ = _errors(rec, sm_true, "off")
    auto, coll = _errors(rec, sm_true, "auto")
    gains = coll.frame_gains  # type: ignore[attr-defined]
    assert gains["horizontal"]["applied"] and gains["vertical"]["applied"]
    est = np.array(gains["horizontal"]["gains"])
    true = np.array([hidden[f"f{i}"] for i in range(1, 25)])
    true /= np.exp(np.mean(np.log(true)))
    assert np.abs(est - true).max() < 0.01
    assert max(auto) < 1e-2 < min(off)


def test_equal_gains_are_left_alone(tmp_path: Path) -> None:
    prof = synthetic_profile()
    sm_true = synthetic_matrices()
    write_slit_recording(tmp_path / "e", prof, sm_true, np.random.default_rng(1), [make_scene("white", 24, 32)])
    _, coll = _errors(Recording(tmp_path / "e"), sm_true, "auto")
    gains = coll.frame_gains  # type: ignore[attr-defined]
    assert not gains["horizontal"]["applied"] and not gains["vertical"]["applied"]
