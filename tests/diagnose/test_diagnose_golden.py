"""Clean data from an *independent* renderer (the shared golden baseline irradiance, with
the noise model applied) must give no findings and no unexplained structure: the
systematic-error allowance covers honest discretisation differences."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from thintact_sdk.diagnosis.imaging import diagnose, load_diagnosis_data
from thintact_sdk.formats.profiles import read_profile_file
from thintact_sdk.formats.recording import RecordingWriter
from thintact_sdk.simulation.noise import signal_to_dn


@pytest.mark.parametrize("device", ["mini", pytest.param("wide", marks=pytest.mark.slow)])
def test_independent_clean_baseline_reports_nothing(golden_dir: Path, tmp_path: Path, device: str) -> None:
    gdir = golden_dir / device
    prof = read_profile_file(gdir / "profile.json").with_physics({})
    scenes = np.load(gdir / "scenes.npy")
    irr = np.load(gdir / "irradiance.npy")
    labels = json.loads((gdir / "labels.json").read_text())
    fs = prof.noise.saturation_dn - prof.noise.black_level_dn
    gains = 0.6 * fs * np.array([1.0, 0.93, 0.82])
    rng = np.random.default_rng(3)
    w = RecordingWriter(tmp_path / "rec", prof)
    for sc, ir, lab in zip(scenes, irr, labels, strict=True):
        dn = signal_to_dn(ir * gains, prof.noise, rng)
        w.add(dn.astype(np.uint16), scene=sc, label=lab)
    rep = diagnose(load_diagnosis_data(tmp_path / "rec")).report
    assert rep["findings"] == [], rep["findings"]
    assert rep["unexplained"]["significant"] is False
    assert rep["baseline"]["chi2_per_dof"] == pytest.approx(1.0, abs=0.03)
