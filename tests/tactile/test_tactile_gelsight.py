"""Photometric stereo on real GelSight ball presses (../shared/data, Taxim pack)."""

from __future__ import annotations

import pytest

from thintact_sdk.tactile.calibration.gelsight_eval import evaluate_gelsight


def test_lut_from_real_presses_predicts_held_out_slopes(shared_dir):
    pack = shared_dir / "data" / "taxim_gelsight_ball_small" / "dataPack_small.npz"
    if not pack.is_file():
        pytest.skip(f"{pack} missing")
    ev = evaluate_gelsight(pack)
    assert set(ev.train).isdisjoint(ev.test) and len(ev.test) >= 20
    # measured 2026-11: slope RMS 0.34 against 0.88 for "flat" (bins 24, even/odd split)
    assert ev.grad_rms < 0.5 * ev.grad_rms_zero
    assert ev.depth_rms_mm < 0.5 * ev.depth_peak_mm


@pytest.mark.slow
def test_image_only_ball_calibration_on_real_presses(shared_dir):
    """What `thintact calibrate-tactile` does with a recording: no annotations used. On the
    whole shared pack, with the ball model chosen among its candidates: heavy, so behind
    ``slow``; the default suite calibrates annotation-free on the vendored presses
    (tests/tactile/test_tactile_depth_real.py::test_vendored_real_presses_figures_and_report)."""
    from thintact_sdk.tactile.calibration.gelsight_eval import evaluate_gelsight_image_only

    pack = shared_dir / "data" / "taxim_gelsight_ball_small" / "dataPack_small.npz"
    if not pack.is_file():
        pytest.skip(f"{pack} missing")
    grad_rms, flat_rms = evaluate_gelsight_image_only(pack)
    # measured 2026-11: 0.48 against 0.88 for "flat" (the annotated caps are themselves rough)
    assert grad_rms < 0.65 * flat_rms
