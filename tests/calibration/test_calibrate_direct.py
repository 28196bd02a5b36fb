"""``thintact calibrate-direct`` (issue 32 item 4): pose → direct generation → filter → bundle,
τ chosen on what validation frames exist, saying when there are too few."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from independent_device import small_profile, write_recording

from thintact_sdk.apps.cli.main import main
from thintact_sdk.formats.profiles import write_profile
from thintact_sdk.formats.recording import RecordingWriter
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.t2s import SystemMatrices


def test_too_few_validation_scenes_fall_back_with_a_warning(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    profile = small_profile(("mono",), rows=24, cols=30, scene=(8, 10), k=32)
    prof = write_profile(profile, tmp_path / "unit.yaml")
    unit = SystemMatrices.direct(profile, scale_dn=1.0)
    white = unit.forward(np.ones((8, 10, 1))) * 900.0 + profile.noise.black_level_dn
    w = RecordingWriter(tmp_path / "rec", profile)
    w.add(np.full_like(white, profile.noise.black_level_dn, dtype=np.float32), np.zeros((8, 10, 1), np.float32), "dark")
    w.add(white.astype(np.float32), np.ones((8, 10, 1), np.float32), "white")
    w.add(white.astype(np.float32), None, "press_1")
    out = tmp_path / "cal"
    assert main(["calibrate", "direct", "--profile", str(prof), "--recording", str(tmp_path / "rec"),
                 "--out", str(out), "--filter-steps", "0"]) == 0
    cap = capsys.readouterr()
    assert "scale 900 DN" in cap.out  # the white frame fixes the scale exactly
    warn = [ln for ln in cap.err.splitlines() if ln.startswith("warning:")]
    assert len(warn) == 1 and "has 1 distinct validation scene" in warn[0] and "needs 4" in warn[0]
    bundle = CalibrationBundle.load(out)
    assert bundle.meta["metrics"]["tau_selection"]["criterion"] != "cross-validation"
    np.testing.assert_allclose(bundle.system_matrices.Pc[0], unit.Pc[0] * 30.0, rtol=1e-5)


def test_enough_validation_scenes_choose_tau_on_the_unit(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    profile = small_profile(("mono",), rows=32, cols=40, scene=(12, 16), k=48)
    prof = write_profile(profile, tmp_path / "unit.yaml")
    write_recording(tmp_path / "rec", profile, seed=1, physics={})
    out = tmp_path / "cal"
    assert main(["calibrate-direct", "--profile", str(prof), "--recording", str(tmp_path / "rec"),
                 "--out", str(out), "--filter-steps", "0"]) == 0
    cap = capsys.readouterr()
    assert "warning:" not in cap.err and "cross-validation" in cap.out
    assert CalibrationBundle.load(out).meta["metrics"]["tau_selection"]["criterion"] == "cross-validation"


def _same_bundle(a: CalibrationBundle, b: CalibrationBundle) -> None:
    for name in ("Po", "Qo", "Pc", "Qc"):
        np.testing.assert_array_equal(getattr(a.system_matrices, name), getattr(b.system_matrices, name))
    assert a.tau == b.tau and a.meta.get("decoder") == b.meta.get("decoder")
    sel = [json.dumps(x.meta["metrics"]["tau_selection"], sort_keys=True) for x in (a, b)]  # NaN-safe
    assert sel[0] == sel[1]


def test_the_library_calibration_is_the_commands(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """``direct_calibration`` writes the bundle ``thintact calibrate-direct`` writes, and the
    command prints the library's scale and validation counts."""
    from thintact_sdk.calibration.matrices_bundle import direct_calibration
    from thintact_sdk.calibration.pipeline import CalibrationOptions
    from thintact_sdk.formats.recording import Recording

    profile = small_profile(("mono",), rows=32, cols=40, scene=(12, 16), k=48)
    prof = write_profile(profile, tmp_path / "unit.yaml")
    write_recording(tmp_path / "rec", profile, seed=1, physics={})
    assert main(["calibrate-direct", "--profile", str(prof), "--recording", str(tmp_path / "rec"),
                 "--out", str(tmp_path / "cli"), "--filter-steps", "0"]) == 0
    out = capsys.readouterr().out
    stages: list[str] = []
    made = direct_calibration(profile, Recording(tmp_path / "rec"), tmp_path / "lib",
                              CalibrationOptions(filter_steps=0), stage=stages.append)
    assert [s[:5] for s in stages] == ["[1/2]", "[2/2]"]
    _same_bundle(CalibrationBundle.load(tmp_path / "cli"), CalibrationBundle.load(tmp_path / "lib"))
    assert made.bundle.tau == CalibrationBundle.load(tmp_path / "lib").tau
    assert f"scale {made.scale_dn:.4g} DN ({made.scale_source})" in out
    assert made.chosen_on_the_unit and made.distinct_scenes >= made.scenes_needed
