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


def test_the_library_calibration_is_the_commands(calibrated: tuple[Path, Path], tmp_path: Path) -> None:
    """``calibrate_from_recording`` writes the bundle ``thintact calibrate --from-recording``
    wrote (same matrices, τ, decoder and verdict), with the stage lines going to ``status``."""
    from thintact_sdk.calibration.pipeline import CalibrationOptions
    from thintact_sdk.calibration.sessions import calibrate_from_recording
    from thintact_sdk.reconstruction.bundle import CalibrationBundle

    rec_dir, cal = calibrated
    lines: list[str] = []
    outcome = calibrate_from_recording(rec_dir, tmp_path / "lib", CalibrationOptions(filter_steps=0),
                                       status=lines.append)
    cli, lib = CalibrationBundle.load(cal), CalibrationBundle.load(tmp_path / "lib")
    for name in ("Po", "Qo", "Pc", "Qc"):
        np.testing.assert_array_equal(getattr(cli.system_matrices, name), getattr(lib.system_matrices, name))
    assert cli.tau == lib.tau and cli.meta.get("decoder") == lib.meta.get("decoder")
    keep = ("mean_psnr_db", "mean_ssim", "verdict")
    assert json.dumps({k: cli.meta["metrics"].get(k) for k in keep}, sort_keys=True) == \
        json.dumps({k: lib.meta["metrics"].get(k) for k in keep}, sort_keys=True)
    assert outcome.path == tmp_path / "lib" and lines


def test_the_wizard_bundle_directory_resumes_or_starts_anew(tmp_path: Path) -> None:
    """``wizard_bundle_dir``: the newest unfinished run is resumed, ``restart`` starts a new
    one, and ``restart`` into a directory holding a capture is refused."""
    from thintact_sdk.calibration.sessions import wizard_bundle_dir
    from thintact_sdk.errors import ProfileError

    prof = synthetic_profile()
    unfinished = tmp_path / "calibrations" / prof.name / "20260101T000000"
    (unfinished / "capture").mkdir(parents=True)
    (unfinished / "capture" / "manifest.json").write_text("{}")
    assert wizard_bundle_dir(prof, None, base=tmp_path) == (unfinished, True)
    fresh, resumed = wizard_bundle_dir(prof, None, restart=True, base=tmp_path)
    assert not resumed and fresh.parent == unfinished.parent and fresh != unfinished
    assert wizard_bundle_dir(prof, tmp_path / "mine", restart=True) == (tmp_path / "mine", False)
    with pytest.raises(ProfileError, match="--restart"):
        wizard_bundle_dir(prof, unfinished, restart=True)


def test_the_library_reconstruction_is_the_commands(calibrated: tuple[Path, Path], tmp_path: Path) -> None:
    """``reconstruct_recording`` writes what ``thintact reconstruct`` writes, file for file and
    bit for bit, and says what it subtracted and which decoder ran."""
    from thintact_sdk.calibration.estimates import reconstruct_recording

    rec_dir, cal = calibrated
    assert main(["reconstruct", str(rec_dir), "--calibration", str(cal), "--out", str(tmp_path / "cli"),
                 "--no-progress"]) == 0
    steps: list[int] = []
    run = reconstruct_recording(rec_dir, cal, tmp_path / "lib", advance=lambda: steps.append(1))
    assert [p.name for p in run.written] == [Path(f.measurement).stem + ".npy"
                                            for f in Recording(rec_dir).frames]
    assert len(steps) == len(run.written) and run.decoder and run.profile_warning is None
    assert "dark" in run.dark_source or "black" in run.dark_source
    for p in run.written:
        np.testing.assert_array_equal(np.load(p), np.load(tmp_path / "cli" / p.name))
