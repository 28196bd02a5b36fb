"""End to end on the virtual bench: the wizard calibrates virtual-mini through the virtual
display and camera plugins; the result is compared with the simulator's two-term fit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thintact_sdk.calibration.pipeline import CalibrationOptions
from thintact_sdk.calibration.wizard import WizardSettings, run_wizard
from thintact_sdk.device.cameras import create_camera
from thintact_sdk.device.registry import get_registry
from thintact_sdk.formats.profiles import Profile, load_profile
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.t2s import SystemMatrices

bench = pytest.importorskip("thintact_virtual.bench", reason="virtual sensor plugin not installed")


def test_wizard_calibrates_virtual_mini(tmp_path: Path) -> None:
    from thintact_sdk.simulation.simulator import Simulator

    d = load_profile("virtual-mini").contract_dict()
    d["display"] = {**d["display"], "settle_s": 0.0}  # the virtual display shows a scene at once
    prof = Profile.model_validate(d)
    cam_settings = {"fps": 0, "seed": 3}
    camera = create_camera(prof, settings=cam_settings)
    display = get_registry().create("display", "virtual", prof, {})
    reference = SystemMatrices.two_term_fit(
        Simulator(prof), scale_dn=bench.signal_scale_dn(prof, {**prof.camera.settings, **cam_settings})
    )
    out = run_wizard(
        prof, tmp_path / "cal", camera, display,
        WizardSettings(frames=4, flush=0, validation=("gelsight:0", "smooth_color")),
        CalibrationOptions(filter_steps=0, filter_scenes=12),
        reference=reference, reference_exposure_us=bench.REFERENCE_EXPOSURE_US,
    )
    bundle = CalibrationBundle.load(tmp_path / "cal")
    assert bundle.system_matrices.sensor_shape == (128, 160) and bundle.system_matrices.scene_shape == (50, 64)
    m = bundle.meta["metrics"]
    assert all(s["converged"] for s in m["solve"])
    assert m["registration"]["passed"]
    # matrices: within a few percent of the simulator's two-term fit (gauge-free operator error)
    assert max(m["reference"]["operator_error"]) < 0.04, m["reference"]["operator_error"]
    assert max(t["open_term"] for t in m["reference"]["term_errors"]) < 0.03
    # reconstructions: close to those from the true matrices on the same measured frames, both
    # with plain Tikhonov held out (what the unit is judged on); the deployed decode (a scene
    # prior where cross-validation chose one) at least as good as the plain one on average
    for label in ("val_gelsight_0", "val_smooth_color"):
        assert m["judged_psnr_db"][label] > m["reference"]["reference_psnr_db"][label] - 4.0
        assert m["psnr_db"][label] > 20.0
    assert np.mean(list(m["psnr_db"].values())) >= np.mean(list(m["judged_psnr_db"].values())) - 0.5
    assert out.path == tmp_path / "cal"
    assert bench.get_scene_slot(prof.name).get() is None  # the display handed the slot back
