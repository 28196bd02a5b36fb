"""Calibration from a recording (offline path): slits found from scenes, dark, exposure,
validation, bundle and report."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from cal_testkit import channel, synthetic_matrices, synthetic_profile, write_slit_recording

from thintact_sdk.calibration.collect import collect_slits
from thintact_sdk.calibration.gauge import operator_error
from thintact_sdk.calibration.pipeline import (
    CalibrationOptions,
    calibrate_recording,
    solve_matrices,
)
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.recording import Recording, RecordingWriter
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.simulation.scenes import make_scene

FAST = CalibrationOptions(filter_steps=0, filter_scenes=8)


def _validation() -> list[np.ndarray]:
    return [make_scene("gelsight", 24, 32, 2), make_scene("smooth_color", 24, 32)]


def _op_errors(rec: Recording, sm_true) -> list[float]:  # type: ignore[no-untyped-def]
    coll = collect_slits(rec)
    sm, reps = solve_matrices(coll, CalibrationOptions(), rec.profile)
    assert all(r.converged for r in reps)
    return [operator_error(channel(sm, c), channel(sm_true, c)) for c in range(3)]


@pytest.mark.report_figures
def test_recording_calibration_matches_the_truth_and_writes_a_bundle(tmp_path: Path) -> None:
    prof = synthetic_profile()
    sm_true = synthetic_matrices()
    write_slit_recording(tmp_path / "rec", prof, sm_true, np.random.default_rng(0), _validation())
    out = calibrate_recording(Recording(tmp_path / "rec"), tmp_path / "cal", FAST, reference=sm_true)
    bundle = CalibrationBundle.load(tmp_path / "cal")
    meta = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert meta["format"] == "thintact-calibration/1" and meta["source"] == "recording"
    assert meta["profile_hash"] == prof.content_hash() and meta["tau"] > 0
    assert bundle.filter is not None and bundle.system_matrices.sensor_shape == (64, 80)
    m = meta["metrics"]
    assert m["dark"].startswith("1 dark frame") and m["slit_frames"] == 24 + 32
    assert all(s["converged"] for s in m["solve"])
    assert max(m["reference"]["operator_error"]) < 0.06  # noise of single frames at ~70 % full scale
    # reconstructions from the calibration are as good as from the true matrices
    for label, ref_psnr in m["reference"]["reference_psnr_db"].items():
        assert m["psnr_db"][label] > ref_psnr - 0.5, (label, m["psnr_db"][label], ref_psnr)
    assert len(out.validation) == 2 and out.passed == m["passed"]
    html = (tmp_path / "cal" / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 3 and ("PASS" in html or "FAIL" in html)
    figures = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", html)
    assert min(len(f) for f in figures) > 1000  # rasterised figures, not stand-ins


def test_slits_are_found_from_scenes_not_labels(tmp_path: Path) -> None:
    prof = synthetic_profile()
    sm_true = synthetic_matrices()
    w = write_slit_recording(tmp_path / "rec", prof, sm_true, None, _validation())
    # a frame with no scene (a touch) and a single-pixel scene are neither slits nor validation
    w.add(np.zeros((64, 80, 3), np.float32) + 64, None, label="hslit_0003")
    dot = np.zeros((24, 32, 3), np.float32)
    dot[3, 4] = 1.0
    w.add(np.zeros((64, 80, 3), np.float32) + 64, dot, label="vslit_0001")
    coll = collect_slits(Recording(tmp_path / "rec"))
    assert coll.slit_frames == 24 + 32
    assert len(coll.validation) == 3  # two validation scenes and the single dot
    assert max(_op_errors(Recording(tmp_path / "rec"), sm_true)) < 1e-2  # DN rounding only


def test_exposure_metadata_and_missing_dark_frame(tmp_path: Path) -> None:
    prof = synthetic_profile()
    sm_true = synthetic_matrices()
    # every third frame recorded at another exposure; no dark frame (profile black level used)
    exposures = {f"f{i}": (10000.0, 5000.0, 20000.0)[i % 3] for i in range(56)}
    write_slit_recording(tmp_path / "rec", prof, sm_true, None, [], dark=False, exposure_of=exposures)
    rec = Recording(tmp_path / "rec")
    coll = collect_slits(rec)
    assert coll.dark_source == "profile black level"
    assert coll.exposure_us is not None and len(coll.frame_scale) > 0
    assert max(_op_errors(rec, sm_true)) < 1e-2  # DN rounding only


def test_recording_without_slits_is_refused(tmp_path: Path) -> None:
    prof = synthetic_profile()
    w = RecordingWriter(tmp_path / "rec", prof)
    w.add(np.zeros((64, 80, 3), np.float32), np.ones((24, 32, 3), np.float32), label="white")
    with pytest.raises(CalibrationError, match="no slit frames"):
        calibrate_recording(Recording(tmp_path / "rec"), tmp_path / "cal", FAST)
