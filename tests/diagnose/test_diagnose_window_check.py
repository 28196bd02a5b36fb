"""The fitted model checked on windows of the unbinned sensor (:mod:`thintact_sdk.diagnosis.imaging.window_check`),
where the whole sensor's kernel is refused (a rotated mask at the paper's size)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.diagnose.test_diagnose_binning import _device, _write_recording
from thintact_sdk.diagnosis.imaging import load_diagnosis_data
from thintact_sdk.diagnosis.imaging.binning import simulate_float32
from thintact_sdk.diagnosis.imaging.forward_model import full_size_stats
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData
from thintact_sdk.diagnosis.imaging.window_check import window_check
from thintact_sdk.errors import ThinTactError

ROTATED = {"mask_misalignment": np.array([1.0, 0.0, 0.0])}


@pytest.fixture(scope="module")
def rotated(tmp_path_factory: pytest.TempPathFactory) -> DiagnosisData:
    path = tmp_path_factory.mktemp("window-check") / "rec"
    _write_recording(_device(32, 48), {"mask_misalignment": {"angle_deg": 1.0, "dx_um": 0.0, "dy_um": 0.0}}, path)
    return load_diagnosis_data(path)


def test_the_right_model_fits_the_windows_to_the_noise_and_a_wrong_one_does_not(rotated: DiagnosisData) -> None:
    right = window_check(rotated, ROTATED)
    assert right.stats is not None and abs(right.excess_z()) < 4, right.to_json()
    wrong = window_check(rotated, {})  # the rotation missed
    assert wrong.stats is not None and wrong.excess_z() > 30, wrong.to_json()


def test_one_window_over_the_whole_sensor_is_the_full_size_check(rotated: DiagnosisData) -> None:
    """This small rotated device's window plan is one window: the whole sensor, with the same
    gains as the full-size check, so the same statistics."""
    full = full_size_stats(rotated, ROTATED, simulate_float32, 1e-3)
    check = window_check(rotated, ROTATED)
    assert check.stats is not None and "1 of 1 windows" in check.where
    assert check.stats.n_pixels == full.n_pixels
    assert check.stats.chi2_per_dof == pytest.approx(full.chi2_per_dof, rel=1e-5)
    assert check.stats.rms_dn == pytest.approx(full.rms_dn, rel=1e-5)


def test_windows_pooled_over_the_whole_sensor(tmp_path: Path) -> None:
    """Every window of a plain grid (2 × 3 windows of 32 × 32 on a 64 × 96 sensor) pools to
    every value of the frames, and a right model's χ²/dof agrees with the full-size check
    (up to the windows' own gains)."""
    _write_recording(_device(64, 96), {}, tmp_path / "rec")
    data = load_diagnosis_data(tmp_path / "rec")
    full = full_size_stats(data, {}, simulate_float32, 1e-3)
    check = window_check(data, {}, n_windows=6)
    assert check.stats is not None and "6 of 6 windows" in check.where
    assert check.stats.n_pixels == full.n_pixels
    assert check.stats.chi2_per_dof == pytest.approx(full.chi2_per_dof, rel=0.03)
    assert check.stats.rms_dn <= full.rms_dn * 1.0001  # each window's own gains fit it at least as well


@pytest.mark.parametrize("values", [{"sensor_blur": np.array([6.0])}, {"veiling_glare": np.array([0.02])}])
def test_effects_that_read_beyond_their_pixel_are_not_evaluated_on_windows(rotated: DiagnosisData,
                                                                           values: dict) -> None:
    check = window_check(rotated, {**ROTATED, **values})
    assert check.stats is None and "a window of the sensor cannot be evaluated alone" in check.note
    assert check.to_json() == {"not_evaluated": check.note}


def test_cli_checks_windows_when_the_whole_sensor_is_refused(tmp_path: Path, rotated: DiagnosisData,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """When the fitted model's full-size kernel is refused (the unbinned stage cannot run),
    ``full_size`` says why and gives the check on windows instead."""
    from thintact_sdk.apps.cli.main import main
    from thintact_sdk.diagnosis.imaging import engine as run_mod

    def refused(*_a: object, **_k: object) -> None:
        raise ThinTactError("physics: a mask rotated by 1° on this device needs 48 sensor windows (test)")

    monkeypatch.setattr(run_mod, "unbinned_stage", refused)
    _write_recording(_device(32, 48), {"mask_misalignment": {"angle_deg": 1.0, "dx_um": 0.0, "dy_um": 0.0}},
                     tmp_path / "rec")
    rc = main(["diagnose", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--quiet", "--bin", "2",
               "--max-effects", "1"])
    assert rc == 0
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert rep["findings"][0]["effect"] == "mask_misalignment"
    full = rep["full_size"]
    assert "needs 48 sensor windows (test)" in full["not_evaluated"]
    win = full["windows"]
    assert "windows of the unbinned sensor" in win["where"] and abs(win["excess_z"]) < 4
