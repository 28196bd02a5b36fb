"""``thintact diagnose``: exit codes, output files and the exact CONTRACTS §6 report keys."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from thintact_sdk.apps.cli.main import main

REPORT_KEYS = {"noise_rms_dn", "baseline", "located", "findings", "final", "unexplained"}


def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["diagnose", str(tmp_path / "missing"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert err.startswith("thintact: error:") and "\n" not in err


def test_recording_without_scenes_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import numpy as np

    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.formats.recording import RecordingWriter

    prof = load_profile("virtual-mini")
    w = RecordingWriter(tmp_path / "rec", prof)
    w.add(np.zeros((prof.sensor.rows, prof.sensor.cols, 3), np.uint16), label="touch")
    rc = main(["diagnose", str(tmp_path / "rec"), "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "no frame with a scene" in capsys.readouterr().err


def test_cli_writes_the_three_outputs(concealed_case: Any, tmp_path: Path) -> None:
    case = concealed_case("clean")
    out = tmp_path / "out"
    rc = main(["diagnose", str(case / "recording"), "--out", str(out), "--quiet"])
    assert rc == 0
    rep = json.loads((out / "report.json").read_text())
    assert set(rep) == REPORT_KEYS
    assert set(rep["baseline"]) == {"rms_dn", "chi2_per_dof"}
    assert set(rep["final"]) == {"rms_dn", "chi2_per_dof"}
    assert set(rep["located"]) == {"summary", "hotspots"}
    assert set(rep["unexplained"]) == {"significant", "summary", "hotspots"}
    for f in rep["findings"]:
        assert set(f) == {"effect", "params", "rms_dn_after", "chi2_per_dof_after", "evidence", "alternatives"}
    prof = json.loads((out / "fitted_profile.json").read_text())
    assert prof["format"] == "thintact-profile/1"
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 3


def test_the_library_diagnosis_is_the_commands(concealed_case: Any, tmp_path: Path) -> None:
    """``thintact diagnose`` only parses, prints and writes: ``diagnose(path)`` gives the same
    report.json content and fitted profile, here binned 2×2 so that the binned stages (the
    unbinned check, the unbinned hotspots, ``binned`` and ``full_size``) are the library's too."""
    from thintact_sdk.diagnosis.imaging import RecordingOptions, diagnose
    from thintact_sdk.formats.profiles import write_profile

    rec = concealed_case("clean") / "recording"
    out = tmp_path / "cli"
    assert main(["diagnose", str(rec), "--out", str(out), "--bin", "2", "--quiet"]) == 0
    d = diagnose(rec, options=RecordingOptions(bin_factor=2))
    cli_report = json.loads((out / "report.json").read_text())
    assert {"binned", "full_size"} <= set(cli_report)
    assert cli_report["binned"]["factor"] == 2
    assert json.loads(json.dumps(d.report)) == cli_report
    lib_profile = write_profile(d.fitted_profile, tmp_path / "fitted_profile.json")
    assert json.loads(lib_profile.read_text()) == json.loads((out / "fitted_profile.json").read_text())
    assert d.fitted_profile.sensor.rows == 2 * d.data.profile.sensor.rows  # the device's own size
