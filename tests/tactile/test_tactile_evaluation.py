"""The benchmark's accuracy measurements, run through the Sensor on the exact block camera."""

from __future__ import annotations

import pytest
from tac_fakes import SLOTS, block_profile, make_registry

from thintact_sdk.device.sensor import Sensor
from thintact_sdk.tactile import Sphere, scene_level_lut
from thintact_sdk.tactile.calibration.evaluation import depth_rms, evaluate_depth, evaluate_markers


@pytest.fixture(scope="module")
def sensor():
    profile = block_profile()
    s = Sensor(profile, registry=make_registry(), lut=scene_level_lut(profile)).open()
    yield s
    s.close()
    SLOTS.clear()


def _show(scene):
    if scene is None:
        SLOTS.pop("tac-block", None)
    else:
        SLOTS["tac-block"] = scene


def test_depth_table_through_the_sensor(sensor):
    seen = []
    rows = evaluate_depth(sensor, _show, {"ball": Sphere(2.0)}, (0.5, 1.0), presses=2,
                          progress=lambda i, n: seen.append((i, n)))
    assert seen[-1] == (4, 4)
    assert [(r.indenter, r.depth_mm, r.presses) for r in rows] == [("ball", 0.5, 2), ("ball", 1.0, 2)]
    for r in rows:  # the block camera is exact: the error is photometric stereo's alone
        assert r.rms_mm < 0.06
        assert r.rms_mm == pytest.approx(r.rms_scene_mm, abs=0.01)


def test_marker_accuracy_through_the_sensor(sensor):
    res = evaluate_markers(sensor, _show, presses=2)
    assert res.rms_mm < 0.02
    assert res.tracked_fraction > 0.9
    assert res.direction_error_deg < 15.0
    assert 0.1 < res.max_true_mm < 0.5


def test_depth_rms_uses_the_thresholded_area():
    import numpy as np

    truth = np.zeros((4, 4))
    truth[1, 1] = 0.5
    est = truth + 0.2
    assert depth_rms(est, truth, 0.1) == pytest.approx(0.2)
    assert np.isnan(depth_rms(est, np.zeros((4, 4)), 0.1))
