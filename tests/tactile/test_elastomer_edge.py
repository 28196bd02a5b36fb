"""The elastomer's smoothing sees the gel beyond the frame: a press whose contact crosses
the frame's edge is shaped there as in the middle of the gel (no zero-depth border), in the
simulator, in the calibration's ball model and in the tactile diagnosis's press model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from thintact_sdk.diagnosis.tactile.press_model import Press, ball_normals
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.tactile.calibration.ball_press import RIGID, BallModel
from thintact_sdk.tactile.interpretation.grid import TactileParams
from thintact_sdk.tactile.simulation.elastomer import gel_window, reach_px, smoothed_in_frame
from thintact_sdk.tactile.simulation.indenters import Sphere
from thintact_sdk.tactile.simulation.membrane import TactileSimulator

MM = 0.1


def _cap(rr: np.ndarray, cc: np.ndarray, centre: tuple[float, float]) -> np.ndarray:
    r2 = ((rr - centre[0]) ** 2 + (cc - centre[1]) ** 2) * MM**2
    return np.clip(np.sqrt(np.clip(4.0 - r2, 0, None)) - 1.4, 0, None)  # R 2 mm, 0.6 deep


def test_smoothing_near_the_edge_is_the_smoothing_of_the_whole_gel():
    shape, sigma = (40, 50), 3.0
    edge = smoothed_in_frame(lambda r, c: _cap(r, c, (20.0, 0.0)), shape, sigma)
    # the truth: the same shape on a grid far larger than the frame, smoothed, cut out
    big = 60
    rr, cc = np.mgrid[-big : shape[0] + big, -big : shape[1] + big].astype(float)
    truth = gaussian_filter(_cap(rr, cc, (20.0, 0.0)), sigma)[big:-big, big:-big]
    np.testing.assert_allclose(edge, truth, atol=1e-9)
    # the former zero border made the same press shallower at the edge
    rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    zero_border = gaussian_filter(_cap(rr, cc, (20.0, 0.0)), sigma, mode="constant")
    assert zero_border.max() < 0.95 * edge.max()
    # away from the edges nothing changes
    inner = smoothed_in_frame(lambda r, c: _cap(r, c, (20.0, 25.0)), shape, sigma)
    np.testing.assert_allclose(inner, gaussian_filter(_cap(rr, cc, (20.0, 25.0)), sigma,
                                                      mode="constant"), atol=1e-12)
    assert reach_px(0.0) == 0 and reach_px(2.0) == 8
    # a press inside the frame keeps the frame as its window (no work beyond it); one
    # crossing the edge carries its part beyond it, and no more
    inside, win = gel_window(lambda r, c: _cap(r, c, (20.0, 25.0)), shape, 12)
    assert inside.shape == shape and win.origin == (0, 0)
    crossing, win = gel_window(lambda r, c: _cap(r, c, (20.0, 0.0)), shape, 12)
    assert crossing.shape == (40, 50 + 12) and win.origin == (0, 12)
    np.testing.assert_array_equal(smoothed_in_frame(lambda r, c: _cap(r, c, (20.0, 0.0)), shape, 0),
                                  _cap(rr, cc, (20.0, 0.0)))


@pytest.mark.parametrize("model", [RIGID, BallModel("sink-in", 0.8)], ids=["rigid", "sink-in"])
def test_ball_models_keep_their_depth_at_the_edge(model):
    params = TactileParams(rows=60, cols=80, mm_per_px=MM, elastomer_sigma_mm=0.3)
    inner = model.depth((60, 80), (30.0, 40.0), 0.6, 2.0, params)
    edge = model.depth((60, 80), (30.0, 0.0), 0.6, 2.0, params)
    assert edge.max() == pytest.approx(inner.max(), rel=1e-9)
    # the half of the press inside the frame is the same half of the interior press
    np.testing.assert_allclose(edge[:, :30], inner[:, 40:70], atol=1e-9)


def test_the_diagnosis_press_model_keeps_its_depth_and_slopes_at_the_edge():
    inner = ball_normals((60, 80), Press(30.0, 40.0, 0.6), 2.0, MM, 0.3)
    edge = ball_normals((60, 80), Press(30.0, 0.0, 0.6), 2.0, MM, 0.3)
    np.testing.assert_allclose(edge.depth_mm[:, :30], inner.depth_mm[:, 40:70], atol=1e-9)
    # central differences at the frame's edge column too
    np.testing.assert_allclose(edge.gx[:, :30], inner.gx[:, 40:70], atol=1e-9)
    np.testing.assert_allclose(edge.gy[:, :30], inner.gy[:, 40:70], atol=1e-9)


def test_simulated_edge_press_is_as_deep_as_an_interior_one_and_its_markers_move_alike():
    params = TactileParams.from_profile(load_profile("virtual-finger"))
    # pixels dividing the marker pitch (1.5 mm), so that every marker sits at the same place
    # relative to the pixel grid and presses centred on markers are sampled alike
    sim = TactileSimulator(replace(params, mm_per_px=0.125))
    ref = sim.reference_markers_mm()
    right = float(ref[:, 0].max())  # the last marker column, within a pitch of the edge
    half_w = sim.params.cols / 2 * sim.params.mm_per_px
    assert right + 2.2 > half_w  # a 2.24 mm contact radius around it crosses the frame's edge
    inner = sim.press(Sphere(3.0), 1.0, (0.0, 0.0), shear_mm=(0.1, 0.0))
    edge = sim.press(Sphere(3.0), 1.0, (right, 0.0), shear_mm=(0.1, 0.0))
    assert float(edge.depth_mm.max()) == pytest.approx(float(inner.depth_mm.max()), rel=1e-6)

    # markers move (shear, and drawn towards the contact) alike at the same place relative
    # to the contact's centre: the smoothing of the contact and of the depth sees the gel
    # beyond the frame
    def motion(scene, centre_x_mm: float) -> dict[tuple[float, float], np.ndarray]:
        rel = np.round(scene.marker_reference_mm - [centre_x_mm, 0.0], 3)
        return {(float(x), float(y)): d for (x, y), d in zip(rel, scene.marker_displacements_mm,
                                                              strict=True)}

    at_edge, in_middle = motion(edge, right), motion(inner, 0.0)
    shared = [k for k in at_edge if k in in_middle and np.hypot(*k) < 3.5]
    assert len(shared) >= 8
    for k in shared:
        np.testing.assert_allclose(at_edge[k], in_middle[k], atol=1e-7)
