"""End to end on the virtual finger: tactile simulator → virtual camera (simulator + noise)
→ decoder → tactile interpreter. Uses the device's calibration bundle when there is one,
else the benchmark's in-memory simulator decoder. Slow."""

from __future__ import annotations

import numpy as np
import pytest

import thintact_sdk as thintact
from thintact_sdk.errors import CalibrationError
from thintact_sdk.tactile import Sphere, TactileSimulator
from thintact_sdk.tactile.calibration.device import calibrate_virtual, scene_slot
from thintact_sdk.tactile.calibration.evaluation import depth_rms, set_reference


@pytest.mark.slow
def test_press_through_the_lensless_path():
    pytest.importorskip("thintact_virtual")
    with thintact.open("virtual-finger", camera_settings={"slot": "tac-e2e", "fps": 0}) as finger:
        slot = scene_slot(finger)
        try:
            finger.read_image()
        except CalibrationError:
            from thintact_sdk.apps.benchmarks.tactile_accuracy import _simulator_decoder

            finger.decoder, _ = _simulator_decoder(finger, slot, "t2s-closed-form")
        finger.lut = calibrate_virtual(finger, presses=8)
        sim = TactileSimulator.for_profile(finger.profile)
        set_reference(finger, slot.set, sim)
        flat = finger.read()
        truth = sim.press(Sphere(2.0), 0.8, (1.0, -1.0), 0.0, shear_mm=(0.2, 0.0))
        slot.set(truth.scene)
        frame = finger.read()
        slot.set(None)
    assert not flat.contact and frame.contact
    assert depth_rms(frame.depth_mm, truth.depth_mm, 0.1) < 0.1
    assert np.isfinite(frame.shear_direction_rad)
    assert abs(frame.shear_direction_rad) < 0.5
