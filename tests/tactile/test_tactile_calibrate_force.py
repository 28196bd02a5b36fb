"""thintact calibrate-force: gains fitted on presses of known load (the elastic ground truth of
the tactile simulator), stored beside the LUT, read back by ForceModel.from_profile."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from thintact_sdk.apps.cli.main import main
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.tactile import Sphere, TactileSimulator
from thintact_sdk.tactile.interpretation.force import ForceModel
from thintact_sdk.tactile.simulation.elastic import Elastomer
from thintact_sdk.tactile.simulation.loaded_press import simulate_loaded_press

STIFFER = Elastomer(youngs_mpa=0.6, poisson=0.48)
"""The 'real' gel: twice as stiff as the profile's default 0.3 MPa."""


@pytest.fixture(scope="module")
def pack(tmp_path_factory: Any) -> tuple[Path, Path, np.ndarray]:
    profile = load_profile("virtual-finger")
    sim = TactileSimulator.for_profile(profile)
    presses = [(5.0, 0.4, 1.0), (5.0, 0.6, 0.6), (5.0, 0.8, 1.0), (8.0, 0.5, 0.5), (8.0, 0.7, 1.0)]
    out = [simulate_loaded_press(sim, STIFFER, Sphere(r), d, (0.3, -0.2), 0.0, 0.4, st)
           for r, d, st in presses]
    folder = tmp_path_factory.mktemp("force")
    np.savez(folder / "presses.npz", f0=sim.flat().scene,
             imgs=np.stack([p.scene.scene for p in out]))
    loads = np.array([p.force_n for p in out])
    (folder / "loads.json").write_text(json.dumps({"loads_n": loads.tolist()}))
    return folder / "presses.npz", folder / "loads.json", loads


def test_calibrate_force_recovers_a_stiffer_gel(pack, tmp_path, monkeypatch, capsys) -> None:
    presses, loads_file, loads = pack
    monkeypatch.setenv("THINTACT_CALIBRATION_PATH", str(tmp_path / "cal"))
    before = ForceModel.from_profile(load_profile("virtual-finger"))
    assert main(["calibrate-force", "--profile", "virtual-finger", "--presses", str(presses),
                 "--loads", str(loads_file)]) == 0
    out = capsys.readouterr().out
    stored = tmp_path / "cal" / "virtual-finger" / "tactile" / "force.json"
    assert f"saved {stored}" in out and "normal force RMS error" in out
    data = json.loads(stored.read_text())
    assert data["format"] == "thintact-force-calibration/1"
    assert data["normal_method"] == "scale" and data["shear_method"] == "fitted"
    rows = data["presses"]
    assert [r["press"] for r in rows] == list(range(5))
    np.testing.assert_allclose([r["given_n"] for r in rows], loads)
    est_z = np.array([r["estimated_n"][2] for r in rows])
    assert np.abs(est_z - loads[:, 2]).max() < 0.12 * loads[:, 2].max()
    assert all(f"{r['press']:5d}" in out for r in rows)
    # the gel is twice as stiff as the profile says: uncalibrated (one scale of the shipped
    # gains, so the uncalibrated estimate is the calibrated one scaled back) far off, then close
    scale = data["force_normal_gain"] / before.normal_gain
    assert data["force_normal_fill_gain"] / before.normal_fill_gain == pytest.approx(scale)
    rel = lambda est: np.sqrt(np.mean(((est - loads[:, 2]) / loads[:, 2]) ** 2))  # noqa: E731
    assert rel(est_z / scale) > 0.25 and rel(est_z) < 0.08
    assert data["normal_rms_rel"] == pytest.approx(rel(est_z))
    assert data["force_shear_gain"] > 1.3 * before.shear_gain
    sheared = [r for r in rows if np.hypot(*r["given_n"][:2]) > 0.1 * r["given_n"][2]]
    assert len(sheared) == 2
    for r in sheared:
        assert r["shear_error_n"] < 0.35 * np.hypot(*r["given_n"][:2])
    after = ForceModel.from_profile(load_profile("virtual-finger"))  # read from the store
    assert (after.normal_gain, after.normal_fill_gain, after.shear_gain) == (
        data["force_normal_gain"], data["force_normal_fill_gain"], data["force_shear_gain"])
    # an existing calibration is only replaced with --force
    assert main(["calibrate-force", "--profile", "virtual-finger", "--presses", str(presses),
                 "--loads", str(loads_file)]) == 2
    assert "--force" in capsys.readouterr().err
    assert main(["calibrate-force", "--profile", "virtual-finger", "--presses", str(presses),
                 "--loads", str(loads_file), "--force"]) == 0


def test_bad_loads_and_packs_are_one_clear_line(pack, tmp_path, monkeypatch, capsys) -> None:
    presses, _, loads = pack
    monkeypatch.setenv("THINTACT_CALIBRATION_PATH", str(tmp_path / "cal"))
    cases = {
        "short.json": ({"loads_n": loads[:2, 2].tolist()}, "2 loads for 5 presses"),
        "word.json": ({"loads_n": [1.0, 1.0, "x", 1.0, 1.0]}, "loads_n[2] is 'x'"),
        "neg.json": ({"loads_n": [1.0, 1.0, 1.0, -1.0, 1.0]}, "loads_n[3] has F_z -1 N"),
        "none.json": ({"loads": []}, "needs a list 'loads_n'"),
    }
    for name, (content, needle) in cases.items():
        (tmp_path / name).write_text(json.dumps(content))
        assert main(["calibrate-force", "--profile", "virtual-finger", "--presses", str(presses),
                     "--loads", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert needle in err and str(tmp_path / name) in err and "Traceback" not in err
    np.savez(tmp_path / "bad.npz", f0=np.zeros((4, 4, 3)))
    (tmp_path / "ok.json").write_text(json.dumps({"loads_n": [1.0]}))
    assert main(["calibrate-force", "--profile", "virtual-finger", "--presses",
                 str(tmp_path / "bad.npz"), "--loads", str(tmp_path / "ok.json")]) == 2
    assert "no array 'imgs'" in capsys.readouterr().err
    assert not (tmp_path / "cal").exists()


def test_a_stored_calibration_for_another_gel_is_refused(tmp_path, monkeypatch) -> None:
    from thintact_sdk.errors import CalibrationError

    stored = tmp_path / "virtual-finger" / "tactile" / "force.json"
    stored.parent.mkdir(parents=True)
    stored.write_text(json.dumps({"format": "thintact-force-calibration/1",
                                  "force_normal_gain": 1.0, "force_normal_fill_gain": 1.0,
                                  "force_shear_gain": 1.0, "elastomer_youngs_mpa": 0.9,
                                  "elastomer_poisson": 0.48}))
    monkeypatch.setenv("THINTACT_CALIBRATION_PATH", str(tmp_path))
    with pytest.raises(CalibrationError, match="elastomer_youngs_mpa 0.9 but profile"):
        ForceModel.from_profile(load_profile("virtual-finger"))
    stored.write_text(json.dumps({"format": "thintact-force-calibration/1",
                                  "force_normal_gain": float("nan")}).replace("NaN", '"nan"'))
    with pytest.raises(CalibrationError, match="force_normal_gain must be a finite number"):
        ForceModel.from_profile(load_profile("virtual-finger"))
