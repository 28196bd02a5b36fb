"""Issue 36: the speed-ups of a paper-size calibration change no figure.

The design prediction images its simulated slits from the simulator's separable expansion
(:func:`~thintact_sdk.calibration.prediction.slit_factors`) instead of a forward pass of each
slit scene; the two must agree to rounding.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.calibration.prediction import _slit_signal_dn, slit_factors, slit_scenes
from thintact_sdk.formats.profiles import Profile, load_profile
from thintact_sdk.simulation.simulator import Simulator


def test_slit_images_from_the_separable_expansion_equal_the_simulator() -> None:
    prof = load_profile("virtual-mini")
    sim = Simulator(prof)
    n, m = prof.scene.rows, prof.scene.cols
    factors = slit_factors(sim, 3)
    assert factors is not None
    idx = [0, 7, n - 1, n, n + 20, n + m - 1]
    gains = np.array([900.0, 800.0, 700.0])
    want = sim.predict_signal_dn(slit_scenes(idx, n, m, 3), gains)
    got = np.stack([_slit_signal_dn(factors, gains, range(i, i + 1), n)[0] for i in idx])
    assert got.dtype == np.float32  # stored as slit_dn takes it: float32 of the float64 products
    np.testing.assert_allclose(got, want.astype(np.float32), rtol=1e-6, atol=1e-6 * np.max(np.abs(want)))


def test_non_separable_physics_falls_back_to_the_simulator() -> None:
    d = load_profile("virtual-mini").contract_dict()
    d["physics"] = {"display_gamma": {"gamma": 2.2}}
    assert slit_factors(Simulator(Profile.model_validate(d)), 3) is None


def test_a_crash_after_the_solve_resumes_without_recomputing_it(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A run killed in a later stage (here: health raising) leaves the solve, filter and
    checkpoints; the next run on the same recording and --out loads them (collect_slits,
    the solve and the filter training are never called again) and writes the same bundle as an
    uninterrupted run, then removes the checkpoints."""
    import json

    import pytest
    from cal_testkit import synthetic_matrices, synthetic_profile, write_slit_recording

    from thintact_sdk.calibration import pipeline
    from thintact_sdk.calibration.pipeline import CalibrationOptions, calibrate_recording
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.simulation.scenes import make_scene

    opts = CalibrationOptions(filter_steps=0, filter_scenes=8)
    write_slit_recording(tmp_path / "rec", synthetic_profile(), synthetic_matrices(), np.random.default_rng(0),
                         [make_scene("gelsight", 24, 32, 2), make_scene("smooth_color", 24, 32)])
    rec = Recording(tmp_path / "rec")
    whole = calibrate_recording(rec, tmp_path / "whole", opts, report=False)
    real_assess = pipeline.assess

    def crash(*a, **k):  # type: ignore[no-untyped-def]
        raise RuntimeError("killed in the health stage")

    monkeypatch.setattr(pipeline, "assess", crash)
    with pytest.raises(RuntimeError):
        calibrate_recording(rec, tmp_path / "cal", opts, report=False)
    assert (tmp_path / "cal" / "stages" / "solve.npz").is_file()
    assert not (tmp_path / "cal" / "calibration.json").exists()

    def never(*a, **k):  # type: ignore[no-untyped-def]
        raise AssertionError("recomputed a finished stage")

    monkeypatch.setattr(pipeline, "assess", real_assess)
    monkeypatch.setattr(pipeline, "collect_slits", never)
    monkeypatch.setattr(pipeline, "solve_matrices", never)
    monkeypatch.setattr(pipeline, "build_bundle", never)
    lines: list[str] = []
    again = calibrate_recording(rec, tmp_path / "cal", opts, report=False, status=lines.append)
    assert not (tmp_path / "cal" / "stages").exists()
    stages = {s["stage"]: s for s in json.loads((tmp_path / "cal" / "calibration.json").read_text())["metrics"]["stages"]}
    assert stages["slit frames and solve"].get("resumed") and stages["joint filter"].get("resumed")
    assert all(s["seconds"] >= 0 and s["peak_rss_mib"] > 0 for s in stages.values())
    assert any(line.startswith("[") and "left" in line for line in lines)  # estimated from timed stages
    np.testing.assert_allclose(again.bundle.system_matrices.Po, whole.bundle.system_matrices.Po)
    np.testing.assert_allclose(again.bundle.filter.phi_f, whole.bundle.filter.phi_f)  # type: ignore[union-attr]
    for v0, v1 in zip(whole.validation, again.validation, strict=True):
        assert abs(v0.psnr_db - v1.psnr_db) < 1e-9
    assert again.prediction is not None and whole.prediction is not None
    assert again.prediction.psnr_db == pytest.approx(whole.prediction.psnr_db)


def test_a_checkpoint_of_another_recording_is_ignored(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from thintact_sdk.calibration.stages import Checkpoints

    (tmp_path / "stages").mkdir()
    a = Checkpoints(tmp_path / "stages", "key-a")
    a.save_json("prediction", {"x": 1})
    assert a.load_json("prediction") == {"x": 1}
    assert Checkpoints(tmp_path / "stages", "key-b").load_json("prediction") is None
    (tmp_path / "stages" / "solve.json").write_text("{not json")
    assert a.load_solve() is None
