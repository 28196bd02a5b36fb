"""The contact region grown by the calibration's rim offset (issue 29 item 1: the contact
radius agrees with √(2Rd − d²)): smoothing moves the curvature's sign change inside the rim,
the calibration measures by how much on the shape it teaches, the interpreter grows its
contact regions by that, and a table file cannot give a nonsense offset."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from thintact_sdk.errors import CalibrationError
from thintact_sdk.tactile.calibration.ball_eval import (
    contact_radius_of_press,
    read_contact_radius_mm,
)
from thintact_sdk.tactile.calibration.ball_press import RIGID, BallModel, contact_rim_offset
from thintact_sdk.tactile.interpretation.contact_region import contact_region
from thintact_sdk.tactile.interpretation.grid import TactileParams
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT, calibrate_lut

MM = 0.1
R = 3.0
SHAPE = (100, 120)
CENTRE = (49.3, 60.6)


def _read(depth: np.ndarray, rim_mm: float) -> float:
    return read_contact_radius_mm(depth, MM, 0.1, MM, rim_mm)


@pytest.mark.parametrize("sigma_mm", [0.15, 0.3])
def test_rim_offset_taught_at_one_depth_brings_other_depths_to_their_contact(sigma_mm):
    """The offset measured on one press of the smoothed rigid cap makes the grown region read
    the contact radius of presses 1.5× shallower and 1.33× deeper within 1.5 pixels (a mask
    grows by whole pixels); without it the region reads them short by more than 0.6
    smoothing widths. (Much shallower presses are bounded by the contact threshold instead:
    the growth never passes it.)"""
    params = TactileParams(rows=SHAPE[0], cols=SHAPE[1], mm_per_px=MM,
                           elastomer_sigma_mm=sigma_mm)
    rim = contact_rim_offset(RIGID, SHAPE, CENTRE, 1.2, R, params, smooth_px=1.0)
    assert rim is not None and rim > 0.6 * sigma_mm
    for press in (0.8, 1.2, 1.6):
        depth = cv2.GaussianBlur(RIGID.depth(SHAPE, CENTRE, press, R, params), (0, 0), 1.0)
        true = contact_radius_of_press(R, press)
        assert true - _read(depth, 0.0) > 0.6 * sigma_mm
        assert _read(depth, rim) == pytest.approx(true, abs=1.5 * MM)


def test_growth_stays_inside_the_pixels_over_the_threshold_and_zero_is_no_growth():
    params = TactileParams(rows=SHAPE[0], cols=SHAPE[1], mm_per_px=MM)
    depth = RIGID.depth(SHAPE, CENTRE, 0.3, R, params)
    raw = contact_region(depth, MM, 0.1, MM)
    assert np.array_equal(contact_region(depth, MM, 0.1, MM, 0.0), raw)
    assert np.array_equal(contact_region(depth, MM, 0.1, MM, 0.04), raw)  # under half a pixel
    huge = contact_region(depth, MM, 0.1, MM, 50.0)
    assert np.array_equal(huge, depth > 0.1)  # never beyond the threshold
    assert not contact_region(np.zeros(SHAPE), MM, 0.1, MM, 1.0).any()


def test_sink_in_shape_reads_outside_its_rim_so_the_calibration_keeps_no_growth():
    """A skirt continuous in slope has no kink at the rim: the measure reads at or outside it
    and the offset is not positive (the calibration clips the median at 0)."""
    params = TactileParams(rows=SHAPE[0], cols=SHAPE[1], mm_per_px=MM)
    rim = contact_rim_offset(BallModel("sink-in", 0.6), SHAPE, CENTRE, 0.5, R, params, 1.0)
    assert rim is not None and rim < 0.05
    assert contact_rim_offset(RIGID, SHAPE, CENTRE, float("nan"), R, params, 1.0) is None


def test_calibration_stores_the_offset_and_the_interpreter_grows_contact_with_it():
    """A simulated calibration stores the offset its own presses show; the interpreter's
    contact area on a simulated press of known depth comes within 8 % of πa² with it, where
    the region without growth is more than 15 % short."""
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.calibration.ball_press import random_ball_presses, scene_level_lut
    from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
    from thintact_sdk.tactile.simulation.membrane import TactileSimulator

    profile = load_profile("virtual-finger")
    lut = scene_level_lut(profile)
    rim = lut.meta["contact_rim_mm"]
    assert 0.05 < rim < 0.5
    sim = TactileSimulator.for_profile(profile)
    areas = {}
    for grow in (True, False):
        table = PhotometricLUT(lut.lo, lut.hi, lut.table, lut.counts,
                               {**lut.meta, "contact_rim_mm": rim if grow else 0.0})
        interp = TactileInterpreter(profile, table)
        interp.set_reference(sim.flat().scene)
        (scene, press), = random_ball_presses(profile, 1, seed=7)
        frame = interp.interpret(scene.scene)
        areas[grow] = frame.contact_area_mm2
        expected = np.pi * contact_radius_of_press(press["ball_radius_mm"],
                                                   float(frame.depth_mm.max())) ** 2
    assert areas[True] == pytest.approx(expected, rel=0.08)
    assert areas[False] < 0.85 * expected


@pytest.mark.parametrize("key,value", [("contact_rim_mm", "0.3"), ("contact_rim_mm", -0.1),
                                       ("contact_rim_mm", 1e9), ("contact_rim_mm", True),
                                       ("contact_rim_mm", [0.3]), ("work_mm_per_px", "abc"),
                                       ("work_mm_per_px", 0)])
def test_table_file_with_a_nonsense_length_is_refused_naming_it(tmp_path, key, value):
    rng = np.random.default_rng(0)
    feats = [rng.random((20, 30, 3)).astype(np.float32) * 0.1]
    grads = [rng.random((20, 30)).astype(np.float32)]
    lut = calibrate_lut(feats, grads, grads, [np.ones((20, 30), bool)], bins=8)
    path = tmp_path / "lut.npz"
    lut.save(path)
    meta = json.loads(path.with_suffix(".json").read_text())
    meta[key] = value
    path.with_suffix(".json").write_text(json.dumps(meta))
    with pytest.raises(CalibrationError, match=f"lut.json: {key} must be a number of mm"):
        PhotometricLUT.load(path)
    meta[key] = 0.25
    path.with_suffix(".json").write_text(json.dumps(meta))
    assert PhotometricLUT.load(path).meta[key] == 0.25


def test_growth_measured_on_balls_brings_other_shapes_closer_to_their_true_contact():
    """The rim is measured on ball presses; a cylinder, a chamfered prism and a cube's edge
    pressed 0.6 and 1.0 mm read their true contact area (where the rigid shape indents the
    gel) more closely with it than without, and never more than 10 % over."""
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.calibration.ball_press import scene_level_lut
    from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
    from thintact_sdk.tactile.simulation.indenters import ChamferedPrism, CubeEdge, Cylinder
    from thintact_sdk.tactile.simulation.membrane import TactileSimulator

    profile = load_profile("virtual-finger")
    lut = scene_level_lut(profile)
    sim = TactileSimulator.for_profile(profile)
    p = sim.params
    interps = {}
    for grow in (True, False):
        table = PhotometricLUT(lut.lo, lut.hi, lut.table, lut.counts,
                               {**lut.meta, "contact_rim_mm": lut.meta["contact_rim_mm"] * grow})
        interps[grow] = TactileInterpreter(profile, table)
        interps[grow].set_reference(sim.flat().scene)
    x = (np.arange(p.cols) - (p.cols - 1) / 2) * p.mm_per_px
    y = (np.arange(p.rows) - (p.rows - 1) / 2) * p.mm_per_px
    xx, yy = np.meshgrid(x, y)
    for shape in (Cylinder(1.5, 6.0), ChamferedPrism(4.0, 3.0, 0.8), CubeEdge(5.0, 4.0)):
        for depth in (0.6, 1.0):
            scene = sim.press(shape, depth, (0.3, -0.2), 20.0).scene
            true = float((shape.indentation_mm(xx, yy, depth, (0.3, -0.2), 20.0) > 0).sum())
            true *= p.mm_per_px**2
            grown, raw = (interps[g].interpret(scene).contact_area_mm2 / true for g in (True, False))
            assert abs(grown - 1) < abs(raw - 1) and grown < 1.1, (shape.name, depth, grown, raw)
