"""The wizard against any Camera/Display: exposure, registration, averaging, resume."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cal_testkit import (
    REFERENCE_EXPOSURE_US,
    FakeCamera,
    FakeDisplay,
    synthetic_matrices,
    synthetic_profile,
)

from thintact_sdk.calibration.gauge import operator_error
from thintact_sdk.calibration.pipeline import CalibrationOptions, channel_matrices
from thintact_sdk.calibration.plan import build_plan
from thintact_sdk.calibration.wizard import WizardSettings, find_unfinished, run_wizard
from thintact_sdk.errors import CalibrationError, DeviceTimeoutError
from thintact_sdk.formats.recording import Recording

FAST = CalibrationOptions(filter_steps=0, filter_scenes=8)
SETTINGS = WizardSettings(frames=2, validation=("gelsight:1", "smooth_color"))


class MirroredDisplay(FakeDisplay):
    def show(self, scene: np.ndarray) -> None:
        super().show(scene[:, ::-1])


def test_wizard_calibrates_a_synthetic_device(tmp_path: Path) -> None:
    prof = synthetic_profile()
    sm = synthetic_matrices(gains_dn=(30.0, 40.0, 25.0))
    disp = FakeDisplay()
    cam = FakeCamera(prof, sm, disp, seed=1)
    out = run_wizard(prof, tmp_path / "cal", cam, disp, SETTINGS, FAST)
    rec = Recording(tmp_path / "cal" / "capture")
    labels = [f.label for f in rec.frames]
    assert labels == [s.label for s in build_plan(prof, SETTINGS.validation)]
    assert all(f.extra["frames"] == 2 for f in rec.frames)
    # exposure changed so the white frame peaks at 70 % of full scale, and recorded
    exposure = rec.frames[1].extra["exposure_us"]
    assert exposure != REFERENCE_EXPOSURE_US and out.bundle.meta["exposure_us"] == pytest.approx(exposure)
    white = rec.measurement(1).astype(float) - prof.noise.black_level_dn
    full = prof.noise.saturation_dn - prof.noise.black_level_dn
    assert 0.6 * full < np.percentile(white, 99.9) < 0.8 * full
    assert out.registration is not None and out.registration.passed
    truth = [channel_matrices(sm, c) for c in range(3)]
    scale = exposure / REFERENCE_EXPOSURE_US
    for c in range(3):
        t = truth[c]
        ref = type(t)(t.Po * np.sqrt(scale), t.Qo * np.sqrt(scale), t.Pc * np.sqrt(scale), t.Qc * np.sqrt(scale))
        assert operator_error(channel_matrices(out.bundle.system_matrices, c), ref) < 0.03
    assert (tmp_path / "cal" / "report.html").is_file()
    assert out.bundle.meta["source"] == "wizard"


def test_registration_catches_a_mirrored_panel_before_the_slit_scan(tmp_path: Path) -> None:
    prof = synthetic_profile()
    disp = MirroredDisplay()
    cam = FakeCamera(prof, synthetic_matrices(), disp, noise=False)
    with pytest.raises(CalibrationError, match="mirrored left-right"):
        run_wizard(prof, tmp_path / "cal", cam, disp, SETTINGS, FAST)
    labels = [f.label for f in Recording(tmp_path / "cal" / "capture").frames]
    assert labels[-1] == "reg_br" and not any(lab.startswith("hslit") for lab in labels)


def test_interrupted_wizard_resumes_without_losing_or_repeating_frames(tmp_path: Path) -> None:
    prof = synthetic_profile()
    sm = synthetic_matrices()
    # uninterrupted reference run (noiseless camera: runs are comparable bit for bit)
    disp = FakeDisplay()
    full = run_wizard(prof, tmp_path / "a", FakeCamera(prof, sm, disp, noise=False), disp, SETTINGS, FAST)
    # the same run, the camera dying after 60 frames
    disp = FakeDisplay()
    with pytest.raises(DeviceTimeoutError):
        run_wizard(prof, tmp_path / "b", FakeCamera(prof, sm, disp, noise=False, fail_after=60), disp, SETTINGS, FAST)
    assert find_unfinished(tmp_path) == tmp_path / "b"
    partial = [f.label for f in Recording(tmp_path / "b" / "capture").frames]
    assert 0 < len(partial) < len(build_plan(prof, SETTINGS.validation))
    disp = FakeDisplay()
    cam = FakeCamera(prof, sm, disp, noise=False)
    resumed = run_wizard(prof, tmp_path / "b", cam, disp, SETTINGS, FAST)
    labels = [f.label for f in Recording(tmp_path / "b" / "capture").frames]
    assert labels[: len(partial)] == partial and len(labels) == len(set(labels))
    assert labels == [f.label for f in Recording(tmp_path / "a" / "capture").frames]
    assert cam.exposure_us == pytest.approx(full.bundle.meta["exposure_us"])  # restored, not re-probed
    for c in range(3):
        np.testing.assert_allclose(resumed.bundle.system_matrices.Po[c], full.bundle.system_matrices.Po[c], rtol=1e-5)
        np.testing.assert_allclose(resumed.bundle.system_matrices.Qc[c], full.bundle.system_matrices.Qc[c], rtol=1e-5)
    assert find_unfinished(tmp_path) is None


def test_resume_refuses_a_changed_profile(tmp_path: Path) -> None:
    prof = synthetic_profile()
    disp = FakeDisplay()
    with pytest.raises(DeviceTimeoutError):
        run_wizard(prof, tmp_path / "c", FakeCamera(prof, synthetic_matrices(), disp, fail_after=10), disp, SETTINGS, FAST)
    other = prof.model_copy(update={"geometry": prof.geometry.model_copy(update={"scene_to_mask_mm": 4.0})})
    disp = FakeDisplay()
    with pytest.raises(CalibrationError, match="different profile"):
        run_wizard(other, tmp_path / "c", FakeCamera(other, synthetic_matrices(), disp), disp, SETTINGS, FAST)


def _with_and_without_the_worker(tmp_path: Path, settings: WizardSettings) -> dict[bool, Any]:
    """The same synthetic unit through the wizard with the capture worker (``True``) and
    without it (``False``), predicting, each in its own directory."""
    prof = synthetic_profile()
    sm = synthetic_matrices(gains_dn=(30.0, 40.0, 25.0))
    opts = CalibrationOptions(filter_steps=0, filter_scenes=8, predict=True)
    runs = {}
    for pipelined in (True, False):
        disp = FakeDisplay()
        runs[pipelined] = run_wizard(prof, tmp_path / str(pipelined), FakeCamera(prof, sm, disp, seed=1),
                                     disp, settings, opts, pipelined=pipelined)
    return runs


def test_pipelined_wizard_solves_during_the_capture_and_gives_the_same_unit(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The capture worker compresses and solves the slits while the wizard captures and
    simulates the prediction's design from the white frame: the bundle is the one the
    wizard makes without it (matrices, filter, validation), the prediction within 0.05 dB,
    and the calibration records the time from the last pattern to the bundle. The worker's
    compressed images are released before the calibration starts (its collection holds
    stacked copies)."""
    from thintact_sdk.calibration import wizard
    from thintact_sdk.calibration.collect import SlitCompressor

    events: list[str] = []
    real_release, real_calibrate = SlitCompressor.release, wizard.calibrate_recording

    def release(self: SlitCompressor) -> None:
        events.append("released")
        real_release(self)

    def calibrate(*a: Any, **k: Any) -> Any:
        events.append("calibrate")
        return real_calibrate(*a, **k)

    monkeypatch.setattr(SlitCompressor, "release", release)
    monkeypatch.setattr(wizard, "calibrate_recording", calibrate)
    runs = _with_and_without_the_worker(tmp_path, SETTINGS)
    assert events == ["released", "calibrate", "calibrate"]  # the pipelined run first
    fast, slow = runs[True], runs[False]
    m = fast.bundle.meta["metrics"]
    assert m["pipelined"]["solve"] and m["pipelined"]["prediction_design"], m["pipelined"]
    assert m["after_last_pattern_s"] > 0 and "after_last_pattern_s" in slow.bundle.meta["metrics"]
    stages = {s["stage"]: s for s in m["stages"]}
    assert "compress" in stages["slit frames and solve"]["pipelined"]
    assert "prediction design" not in stages  # done during the capture
    for name in ("Po", "Qo", "Pc", "Qc"):
        np.testing.assert_array_equal(getattr(fast.bundle.system_matrices, name),
                                      getattr(slow.bundle.system_matrices, name))
    assert [v.psnr_db for v in fast.validation] == [v.psnr_db for v in slow.validation]
    assert fast.prediction is not None and slow.prediction is not None
    for label, db in slow.prediction.psnr_db.items():
        assert abs(fast.prediction.psnr_db[label] - db) < 0.05


def test_the_scene_priors_are_chosen_on_the_design_during_the_capture(tmp_path: Path) -> None:
    """With validation scenes that make two folds, the capture worker chooses each decoder's
    scene prior on the design's simulated validation frames while the wizard captures; after
    the last pattern the unit compares plain Tikhonov with that prior alone (issue 36), says
    so in its report, and deploys a prior only where its own frames agree."""
    from thintact_sdk.calibration.tau import prior_candidates

    settings = WizardSettings(frames=2, validation=("gelsight:1", "smooth_color", "gelsight:5", "checker"))
    runs = _with_and_without_the_worker(tmp_path, settings)
    fast, slow = (runs[k].bundle.meta["metrics"] for k in (True, False))
    assert "priors" in fast["pipelined"]["seconds"] and not fast["pipelined"]["errors"], fast["pipelined"]
    search = fast["tau_selection"]["scene_prior_search"]
    assert set(search) == {"t2s-closed-form"} and "design's simulated validation frames" in search["t2s-closed-form"]
    assert "scene_prior_search" not in slow["tau_selection"]
    # the unit searched every candidate without the worker, one at most with it
    assert len(slow["tau_selection"]["scene_prior_candidates"]["t2s-closed-form"]) == len(prior_candidates())
    narrowed = fast["tau_selection"].get("scene_prior_candidates", {}).get("t2s-closed-form", [])
    assert len(narrowed) == (0 if search["t2s-closed-form"].startswith(
        "chosen on the design's simulated validation frames during the capture: none") else 1)
    deployed = runs[True].bundle.meta.get("scene_prior", {}).get("t2s-closed-form")
    if deployed is not None:  # only a prior the unit's own frames chose
        assert [(c["alpha"], c["k0"]) for c in narrowed] == [(deployed["alpha"], deployed["k0"])]


def test_design_priors_choose_as_the_units_own_search_does() -> None:
    """:func:`design_priors` is the unit's prior search on the design's frames: the same
    candidates, τ cross-validation and median-scene rule."""
    from thintact_sdk.calibration.capture_worker import DESIGN_PRIOR_SEED, design_priors
    from thintact_sdk.calibration.prediction import design_for_prediction, design_signals
    from thintact_sdk.calibration.tau import cross_validate_prior, tau_grid
    from thintact_sdk.calibration.validation import make_decoder
    from thintact_sdk.reconstruction.bundle import CalibrationBundle
    from thintact_sdk.simulation.scenes import make_scene

    prof = synthetic_profile()
    design = design_for_prediction(prof, synthetic_matrices(gains_dn=(30.0, 40.0, 25.0)), 2)
    n, m = prof.scene.rows, prof.scene.cols
    validation = [(f"v{i}", make_scene(k, n, m, s).astype(np.float32))
                  for i, (k, s) in enumerate((("gelsight", 1), ("smooth_color", 0), ("gelsight", 5), ("checker", 0)))]
    chosen = design_priors(prof, design, validation)
    assert chosen is not None and set(chosen) == {"t2s-closed-form"}
    scenes = [x for _, x in validation]
    signals = design_signals(design, scenes, np.random.default_rng(DESIGN_PRIOR_SEED))
    bundle = CalibrationBundle.create(prof, design.design, None, tau=1.0, source="simulator")
    cv = cross_validate_prior(lambda p: make_decoder(prof, bundle, "t2s-closed-form", prior=p), "t2s-closed-form",
                              signals, scenes, [lb for lb, _ in validation], tau_grid(design.design))
    assert cv is not None and chosen["t2s-closed-form"] == cv.prior
    assert design_priors(prof, design, validation[:2]) is None  # two scenes make no two folds
