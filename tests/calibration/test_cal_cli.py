"""``thintact calibrate --from-recording`` and ``thintact reconstruct`` through the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cal_testkit import synthetic_matrices, synthetic_profile, write_slit_recording

from thintact_sdk.apps.cli.main import main
from thintact_sdk.formats.recording import Recording
from thintact_sdk.simulation.scenes import make_scene


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("cli")
    prof = synthetic_profile()
    write_slit_recording(root / "rec", prof, synthetic_matrices(),
                         np.random.default_rng(2), [make_scene("gelsight", 24, 32, 1)])
    rc = main(["calibrate", "--from-recording", str(root / "rec"), "--out", str(root / "cal"),
               "--filter-steps", "0", "--no-progress"])
    assert rc in (0, 1)
    return root / "rec", root / "cal"


def test_calibrate_from_recording_prints_the_verdict(calibrated: tuple[Path, Path],
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    _, cal = calibrated
    meta = json.loads((cal / "calibration.json").read_text())
    assert meta["source"] == "recording" and (cal / "filter.npz").is_file()
    assert (cal / "system_matrices.npz").is_file() and (cal / "report.html").is_file()


def test_reconstruct_writes_one_estimate_per_frame(calibrated: tuple[Path, Path], tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    rec_dir, cal = calibrated
    assert main(["reconstruct", str(rec_dir), "--calibration", str(cal), "--out", str(tmp_path / "x"),
                 "--no-progress"]) == 0
    rec = Recording(rec_dir)
    names = sorted(p.name for p in (tmp_path / "x").iterdir())
    assert names == sorted(Path(f.measurement).name for f in rec.frames)
    est = np.load(tmp_path / "x" / Path(rec.frames[-1].measurement).name)
    assert est.shape == (24, 32, 3) and est.dtype == np.float32
    truth = rec.scene(len(rec) - 1)
    assert truth is not None
    assert float(np.corrcoef(est.ravel(), truth.ravel())[0, 1]) > 0.8


def test_cli_errors_are_one_line(tmp_path: Path, calibrated: tuple[Path, Path],
                                 capsys: pytest.CaptureFixture[str]) -> None:
    rec_dir, _ = calibrated
    assert main(["reconstruct", str(rec_dir), "--calibration", str(tmp_path / "nope"), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("thintact: error:") and "not found" in err and "\n" not in err
    assert main(["calibrate", "--from-recording", str(rec_dir)]) == 2
    assert "--out" in capsys.readouterr().err
    assert main(["calibrate", "--from-recording", str(tmp_path / "missing"), "--out", str(tmp_path / "c")]) == 2
