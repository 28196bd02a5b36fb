"""Bring your own matrices: .npz / .mat import and export, FlatCam one-term matrices, clear
shape errors, and a bundle that the τ selection, the decoders and `reconstruct` work on."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from independent_device import small_profile, write_recording

from thintact_sdk.apps.cli.main import main
from thintact_sdk.calibration.collect import collect_slits
from thintact_sdk.calibration.pipeline import (
    CalibrationOptions,
    bundle_from_matrices,
    solve_matrices,
)
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.matrices import export_matrices, import_matrices
from thintact_sdk.formats.recording import Recording
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.metrics import psnr


@pytest.fixture(scope="module")
def unit(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    root = tmp_path_factory.mktemp("import")
    profile = small_profile(("mono",))
    rec = write_recording(root / "rec", profile, seed=3)
    sm, _ = solve_matrices(collect_slits(rec), CalibrationOptions(), profile)
    return profile, rec, sm


@pytest.mark.parametrize("suffix", [".npz", ".mat"])
def test_export_then_import_round_trips(unit, tmp_path: Path, suffix: str) -> None:  # type: ignore[no-untyped-def]
    profile, _, sm = unit
    path = export_matrices(sm, tmp_path / f"m{suffix}")
    back = import_matrices(path, profile)
    for key in ("Po", "Qo", "Pc", "Qc"):
        np.testing.assert_allclose(getattr(back, key), getattr(sm, key), rtol=1e-12)
    assert back.meta["source"] == "import" and back.meta["model"] == "t2s"


def test_flatcam_matrices_from_matlab_and_shape_errors(unit, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from scipy.io import savemat

    profile, _, sm = unit
    savemat(tmp_path / "fc.mat", {"Phi_L": sm.Pc[0], "Phi_R": sm.Qc[0]})
    fc = import_matrices(tmp_path / "fc.mat", profile)
    assert fc.meta["model"] == "flatcam" and not fc.Po.any() and not fc.Qo.any()
    np.testing.assert_allclose(fc.Pc[0], sm.Pc[0])
    savemat(tmp_path / "bad.mat", {"Phi_L": sm.Pc[0].T, "Phi_R": sm.Qc[0]})
    with pytest.raises(CalibrationError, match=r"bad\.mat: Phi_L is 24×64, expected 64×24"):
        import_matrices(tmp_path / "bad.mat", profile)
    np.savez(tmp_path / "none.npz", A=np.zeros(3))
    with pytest.raises(CalibrationError, match="expected Po, Qo, Pc, Qc"):
        import_matrices(tmp_path / "none.npz", profile)


@pytest.mark.parametrize("scale, peak", [(1e300, "e\\+30"), (1e-300, "e-30"), (np.inf, None)])
def test_matrices_a_bundle_cannot_hold_are_refused(unit, tmp_path: Path, scale: float, peak) -> None:  # type: ignore[no-untyped-def]
    """×1e300 matrices were written as inf/NaN bundles (exit 0), ×1e-300 as zeros."""
    profile, _, sm = unit
    with np.errstate(over="ignore"):
        np.savez(tmp_path / "m.npz", Po=sm.Po * scale, Qo=sm.Qo, Pc=sm.Pc, Qc=sm.Qc)
    match = "Po holds NaN or infinite" if peak is None else rf"m\.npz: Po peaks at .*{peak}"
    with pytest.raises(CalibrationError, match=match):
        import_matrices(tmp_path / "m.npz", profile)


@pytest.mark.parametrize("model", ["t2s", "flatcam"])
def test_imported_bundle_chooses_tau_and_reconstructs(unit, tmp_path: Path, model: str) -> None:  # type: ignore[no-untyped-def]
    profile, rec, sm = unit
    if model == "t2s":
        path = export_matrices(sm, tmp_path / "m.npz")
    else:
        np.savez(tmp_path / "m.npz", Phi_L=sm.Pc, Phi_R=sm.Qc)
        path = tmp_path / "m.npz"
    bundle = bundle_from_matrices(profile, import_matrices(path, profile), tmp_path / "cal",
                                  CalibrationOptions(filter_steps=0), recording=rec)
    assert CalibrationBundle.load(tmp_path / "cal").meta["source"] == "import"
    assert bundle.meta["metrics"]["tau_selection"]["criterion"] == "cross-validation"
    assert main(["reconstruct", str(rec.root), "--calibration", str(tmp_path / "cal"),
                 "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    r = Recording(rec.root)
    i = next(i for i, f in enumerate(r.frames) if f.label == "val_gelsight_0")
    est = np.load(tmp_path / "out" / f"{Path(r.frames[i].measurement).stem}.npy")
    truth = r.scene(i).mean(axis=2, keepdims=True)
    floor = 18.0 if model == "t2s" else 8.0  # one term cannot explain the open light (10.4 dB)
    assert psnr(np.clip(est, 0, 1), truth) > floor


def test_import_and_export_through_the_cli(unit, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # type: ignore[no-untyped-def]
    from thintact_sdk.formats.profiles import write_profile

    profile, rec, sm = unit
    write_profile(profile, tmp_path / "p.json")
    export_matrices(sm, tmp_path / "m.mat")
    assert main(["calibrate-import", str(tmp_path / "m.mat"), "--profile", str(tmp_path / "p.json"),
                 "--out", str(tmp_path / "cal"), "--recording", str(rec.root), "--filter-steps", "0"]) == 0
    assert "cross-validation" in capsys.readouterr().out
    assert main(["calibrate-export", str(tmp_path / "cal"), "--out", str(tmp_path / "back.npz")]) == 0
    np.testing.assert_allclose(import_matrices(tmp_path / "back.npz", profile).Pc, sm.Pc, rtol=1e-6)
    np.savez(tmp_path / "wrong.npz", Po=sm.Po[:, :10], Qo=sm.Qo, Pc=sm.Pc, Qc=sm.Qc)
    assert main(["calibrate-import", str(tmp_path / "wrong.npz"), "--profile", str(tmp_path / "p.json"),
                 "--out", str(tmp_path / "cal2")]) == 2
    err = capsys.readouterr().err
    assert "wrong.npz: Po is 1×10×24, expected 64×24" in err and "\n" not in err.strip()


def test_the_library_import_is_the_commands(unit, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # type: ignore[no-untyped-def]
    """``import_calibration`` writes the bundle ``thintact calibrate-import`` writes."""
    from thintact_sdk.calibration.matrices_bundle import import_calibration
    from thintact_sdk.formats.profiles import write_profile

    profile, rec, sm = unit
    write_profile(profile, tmp_path / "p.json")
    export_matrices(sm, tmp_path / "m.npz")
    assert main(["calibrate-import", str(tmp_path / "m.npz"), "--profile", str(tmp_path / "p.json"),
                 "--out", str(tmp_path / "cli"), "--recording", str(rec.root), "--filter-steps", "0"]) == 0
    printed = capsys.readouterr().out
    got, bundle = import_calibration(tmp_path / "m.npz", profile, tmp_path / "lib",
                                     CalibrationOptions(filter_steps=0), Recording(rec.root))
    cli, lib = CalibrationBundle.load(tmp_path / "cli"), CalibrationBundle.load(tmp_path / "lib")
    for name in ("Po", "Qo", "Pc", "Qc"):
        np.testing.assert_array_equal(getattr(cli.system_matrices, name), getattr(lib.system_matrices, name))
    assert cli.tau == lib.tau == bundle.tau
    same = [json.dumps(b.meta["metrics"]["tau_selection"], sort_keys=True) for b in (cli, lib)]  # NaN-safe
    assert same[0] == same[1]
    assert f"imported {got.meta['model']} matrices" in printed and f"tau {bundle.tau:.4g} DN²" in printed
