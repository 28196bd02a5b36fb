"""The bench row of concealed tactile effects through the lensless path (slow: a virtual
sensor, its LUT calibration and a diagnosis of reconstructed presses)."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.diagnosis.tactile.lensless import CONCEALED_GAMMA, conceal


def test_conceal_applies_field_exposure_and_gamma() -> None:
    scene = np.full((10, 20, 3), 0.5, np.float32)
    out = conceal(scene, np.ones(3))
    assert out[5, 10, 0] == pytest.approx(0.5**CONCEALED_GAMMA, rel=0.02)  # field ≈ 1 at the centre
    assert out[-1, 10, 0] > out[0, 10, 0]  # brighter towards +y (rows) in R
    assert out[5, 0, 0] > out[5, -1, 0]  # darker towards +x in R
    assert np.all(conceal(scene, np.full(3, 1.1)) > out)


@pytest.mark.slow
def test_concealed_rows_through_the_lensless_path() -> None:
    from thintact_sdk.device.registry import get_registry
    from thintact_sdk.device.sensor import Sensor
    from thintact_sdk.diagnosis.tactile.lensless import evaluate_concealed
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.calibration.device import calibrate_virtual, scene_slot

    profile = load_profile("virtual-finger")
    settings = dict(profile.decoder.settings)
    settings["tau"] = 5000
    dec = get_registry().create("decoder", profile.decoder.plugin, profile, settings)
    with Sensor(profile, camera_settings={"slot": "t", "fps": 0, "seed": 0}, decoder=dec) as s:
        slot = scene_slot(s)
        s.lut = calibrate_virtual(s, 8, seed=0)
        rows, rep = evaluate_concealed(s, slot.set, presses=1)
    names = [f["effect"] for f in rep["findings"]]
    assert {"illumination_field", "exposure_drift"} <= set(names)
    assert rep["final"]["chi2_per_dof"] < rep["baseline"]["chi2_per_dof"]
    assert all(np.isfinite([r.plain_mm, r.concealed_mm, r.corrected_mm]).all() for r in rows)
