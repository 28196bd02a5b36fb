"""Depth that holds on real gels (issue 29): free-boundary integration, the colour + position
gradient network, the press circle on one-channel images, ball-press figures."""

from __future__ import annotations

import json

import numpy as np
import pytest

from thintact_sdk.errors import CalibrationError
from thintact_sdk.tactile.calibration.ball_eval import ball_cap, fit_sphere, press_figures
from thintact_sdk.tactile.calibration.ball_press import find_press_circle
from thintact_sdk.tactile.interpretation.gradient_model import MLPGradient, train_mlp
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT, calibrate_lut, net_path
from thintact_sdk.tactile.interpretation.poisson import integrate_gradients

MM = 0.1


def _cap(shape=(90, 120), centre=(45.0, 60.0), press=0.8, radius=2.0):
    d, gx, gy, a_px = ball_cap(shape, centre, press, radius, MM)
    return d, gx, gy, a_px


def test_press_circle_on_one_channel_image():
    yy, xx = np.mgrid[0:60, 0:80]
    img = np.where((yy - 30) ** 2 + (xx - 41) ** 2 < 100, 0.3, 0.0).astype(np.float32)
    (r, c), radius = find_press_circle(img)
    assert abs(r - 30) < 0.5 and abs(c - 41) < 0.5 and abs(radius - 10) < 1
    assert find_press_circle(img[..., None]) == ((r, c), radius)


@pytest.mark.parametrize("centre", [(45.0, 0.0), (45.0, 4.0), (-6.0, 60.0), (89.0, 119.0)],
                         ids=["on-left-edge", "near-left-edge", "beyond-top", "corner"])
def test_press_circle_cut_by_the_frame_is_found_where_the_press_is(centre):
    """A press cut by the frame's edge: its visible part's centroid lies inside the frame and
    its area is short, so the circle comes from the rim away from the edge."""
    yy, xx = np.mgrid[0:90, 0:120]

    def press(at):
        dist = np.hypot(yy - at[0], xx - at[1])
        img = np.where(dist < 15, 0.2 + 0.1 * (1 - (dist / 15) ** 2), 0.0).astype(np.float32)
        return img + np.random.default_rng(1).normal(0, 0.003, img.shape).astype(np.float32), dist

    img, dist = press(centre)
    (r, c), radius = find_press_circle(img)
    assert abs(r - centre[0]) < 1.0 and abs(c - centre[1]) < 1.0
    (rm, cm), radius_middle = find_press_circle(press((45.0, 60.0))[0])
    assert abs(rm - 45) < 0.5 and abs(cm - 60) < 0.5
    assert abs(radius - radius_middle) < 1.0  # the same press in the middle of the frame
    # what the centroid of the visible part says (the rule for presses inside the frame)
    inside = dist < 15
    assert np.hypot(yy[inside].mean() - centre[0], xx[inside].mean() - centre[1]) > 2.5


def test_press_circle_refuses_a_vector():
    with pytest.raises(CalibrationError, match="N × M"):
        find_press_circle(np.zeros(10, np.float32))


@pytest.mark.parametrize("centre", [(45.0, 60.0), (45.0, 3.0), (2.0, 118.0)])
def test_free_boundary_keeps_presses_at_the_edge(centre):
    d, _, _, _ = _cap(centre=centre)
    gy, gx = np.gradient(d, MM)
    free = integrate_gradients(gx, gy, MM)
    assert abs(float(free.max()) - float(d.max())) < 0.05 * float(d.max())
    assert float(np.sqrt(np.mean((free - d) ** 2))) < 0.02
    if centre[1] < 10:  # the pinned border loses most of an edge press
        zero = integrate_gradients(gx, gy, MM, boundary="zero")
        assert float(zero.max()) < 0.7 * float(d.max())


def test_free_boundary_removes_a_constant_slope_bias():
    d, _, _, _ = _cap()
    gy, gx = np.gradient(d, MM)
    rec = integrate_gradients(gx + 0.01, gy - 0.02, MM)
    far = d == 0
    assert float(np.abs(rec[far]).max()) < 0.03
    with pytest.raises(ValueError, match="boundary"):
        integrate_gradients(gx, gy, MM, boundary="mirror")  # type: ignore[arg-type]


def test_sphere_fit_and_press_figures_on_an_exact_cap():
    d, gx, gy, a_px = _cap(press=0.8)
    radius, (r, c) = fit_sphere(d, MM)
    assert abs(radius - 2.0) < 1e-6 and abs(r - 45) < 1e-6 and abs(c - 60) < 1e-6
    f = press_figures(d, gx, gy, 2.0, MM, contact_threshold_mm=0.0)
    assert abs(f.press_mm - 0.8) < 1e-3 and f.depth_rms_mm < 1e-3 and f.slope_rms < 1e-2
    # the slope's kink at the rim of an exact cap moves the one-pixel curvature's sign
    # change about 1.4 px inwards (a real membrane has no kink: the next test)
    assert -0.1 < f.contact_radius_mm / f.contact_radius_expected_mm - 1 < 0
    assert not f.edge
    assert f.slope_rms_gentle < 1e-2  # the slopes under 45 degrees alone
    deep, dx, dy, _ = _cap(press=1.5)  # slopes up to 1.6 inside 0.9 of the contact
    short = press_figures(deep, dx * 0.8, dy * 0.8, 2.0, MM, contact_threshold_mm=0.0)
    assert 0 < short.slope_rms_gentle < 0.8 * short.slope_rms  # the error grows with the slope
    flat = press_figures(d * 0.5, gx * 0.5, gy * 0.5, 2.0, MM)
    assert flat.sphere_radius_mm > 3.0  # a cap too flat reads as a larger ball


@pytest.mark.parametrize("skirt_mm", [0.3, 0.6, 1.2])
def test_contact_region_leaves_a_sink_in_skirt_out(skirt_mm):
    """A gel that sinks in around the ball (ball surface inside the contact, a K0 skirt
    outside, the elastomer blur): the contact region is the ball's contact circle, where the
    region deeper than the contact threshold takes the skirt in."""
    from thintact_sdk.tactile.calibration.ball_press import BallModel
    from thintact_sdk.tactile.interpretation.contact_region import contact_region
    from thintact_sdk.tactile.interpretation.grid import TactileParams

    params = TactileParams(rows=90, cols=120, mm_per_px=MM)
    model = BallModel("sink-in", skirt_mm)
    h = 0.5
    dist = np.hypot(*(np.mgrid[0:90, 0:120] - np.array([45.0, 60.0])[:, None, None])) * MM
    _, press, a = model.rigid_depth(dist, h, 2.0)
    d = model.depth((90, 120), (45.0, 60.0), h, 2.0, params)
    gy, gx = np.gradient(d, MM)
    region = contact_region(d, MM, 0.1, MM)
    # the sign change is found to within about the blur: elastomer (0.25 mm) + one pixel
    blur = 1.5 * (params.elastomer_sigma_mm + MM)
    assert abs(np.sqrt(region.sum() / np.pi) * MM - a) < blur
    f = press_figures(d, gx, gy, 2.0, MM, 0.1)
    assert abs(f.contact_radius_mm - a) < blur
    assert f.skirt_radius_mm > f.contact_radius_mm
    assert abs(f.press_mm - press) < 0.05 and f.depth_rms_mm < 0.03  # the ball's surface
    # no contact without a pixel over the threshold; a flat punch's face is filled in
    assert not contact_region(d * 0.05, MM, 0.1, MM).any()
    punch = np.zeros((90, 120))
    punch[30:60, 40:80] = 0.5
    from scipy.ndimage import gaussian_filter

    punch = gaussian_filter(punch, 2.5)
    region = contact_region(punch, MM, 0.1, MM)
    assert region[32:58, 42:78].all() and not region[:20].any()
    # a punch cut by the frame's edge: the rim closes along the edge
    cut = contact_region(punch[:, 55:], MM, 0.1, MM)
    assert cut[32:58, :20].all()
    # a face over the whole frame has no curvature anywhere: it counts whole
    assert contact_region(np.full((20, 30), 0.4), MM, 0.1, MM).all()


@pytest.mark.parametrize("press", [0.4, 0.8, 1.4])
def test_taught_contact_ratio_is_what_the_measure_reads_on_the_taught_shape(press):
    """A reconstruction that is exactly the calibration's smoothed rigid cap reads, through the
    contact measure, the taught ratio: the reconstruction's share of a ratio under 1 is 1."""
    from scipy.ndimage import gaussian_filter

    from thintact_sdk.tactile.calibration.ball_eval import summarise, taught_contact_ratio
    from thintact_sdk.tactile.calibration.ball_press import BallModel

    shape, centre, blur = (90, 120), (44.6, 60.3), 0.25
    sharp, _, _, _ = _cap(shape, centre, press)
    d = gaussian_filter(sharp, blur / MM, mode="constant")
    gy, gx = np.gradient(d, MM)
    f = press_figures(d, gx, gy, 2.0, MM, 0.1, smooth_mm=MM)
    measured = f.contact_radius_mm / f.contact_radius_expected_mm
    taught = taught_contact_ratio(BallModel(), shape, f.centre_rc, f.peak_mm, 2.0, MM, blur,
                                  0.1, MM)
    assert measured < 0.97  # the measure reads the smoothed rim inside the contact
    assert taught == pytest.approx(measured, abs=0.02)
    # the unsmoothed cap reads closer to 1 than the smoothed one: the blur is the bias
    assert taught < taught_contact_ratio(BallModel(), shape, f.centre_rc, float(sharp.max()),
                                         2.0, MM, 0.0, 0.1, MM) <= 1.0
    # a sink-in skirt deepens the peak for the same contact: the ratio it reads is lower
    assert taught_contact_ratio(BallModel("sink-in", 0.6), shape, f.centre_rc, f.peak_mm, 2.0,
                                MM, blur, 0.1, MM) < taught
    f.contact_ratio_taught = taught
    s = summarise([f], 2.0)
    assert s["contact_ratio_taught_median"] == pytest.approx(taught)
    f.contact_ratio_taught = float("nan")
    assert summarise([f], 2.0)["contact_ratio_taught_median"] is None
    # nothing pressed: no ratio
    assert np.isnan(taught_contact_ratio(BallModel(), shape, centre, 0.0, 2.0, MM, blur))


@pytest.mark.parametrize("meta", [None, [], "rigid", {"model": "cone"},
                                  {"model": "sink-in", "skirt_length_mm": "x"},
                                  {"model": "sink-in", "skirt_length_mm": -1}])
def test_taught_shape_from_a_damaged_lut_json_is_left_out(meta):
    from thintact_sdk.tactile.calibration.press_pack import _taught_shape

    assert _taught_shape(meta) is None


def _network(tmp_path, steps=200):
    rng = np.random.default_rng(0)
    d, gx, gy, _ = _cap(shape=(40, 50), centre=(20.0, 25.0), press=0.5)
    change = np.stack([gx, gy, -gx - gy], -1).astype(np.float32) * 0.2
    image = 0.5 + change
    valid = rng.random(gx.shape) < 0.8
    return train_mlp([change], [image], [gx], [gy], [valid], hidden=8, steps=steps), change, image


def test_network_round_trip_and_flat_reference(tmp_path):
    net, change, image = _network(tmp_path)
    gx, gy = net.predict(change, image)
    assert gx.shape == change.shape[:2] and gx.dtype == np.float32
    zx, zy = net.predict(np.zeros_like(change), image - change)
    assert float(np.abs(zx).max()) == 0.0 and float(np.abs(zy).max()) == 0.0
    p = net.save(tmp_path / "net.npz")
    back = MLPGradient.load(p)
    bx, by = back.predict(change, image)
    np.testing.assert_array_equal(bx, gx)
    np.testing.assert_array_equal(by, gy)
    with pytest.raises(CalibrationError, match="working grid"):
        back.predict(change[:-1], image[:-1])


def test_network_file_with_an_object_array_is_refused(tmp_path):
    p = tmp_path / "bad.npz"
    np.savez(p, w0=np.array([object()], dtype=object), b0=np.zeros(2), w1=np.zeros((2, 2)),
             b1=np.zeros(2), w2=np.zeros((2, 2)), b2=np.zeros(2), shape=np.array([2, 2]))
    with pytest.raises(CalibrationError, match="w0"):
        MLPGradient.load(p)
    np.savez(p, w0=np.zeros((8, 4), np.float32), b0=np.zeros(3, np.float32),
             w1=np.zeros((4, 4), np.float32), b1=np.zeros(4, np.float32),
             w2=np.zeros((4, 2), np.float32), b2=np.zeros(2, np.float32), shape=np.array([2, 2]))
    with pytest.raises(CalibrationError, match="b0"):
        MLPGradient.load(p)


def test_lut_stores_the_chosen_network_beside_it(tmp_path):
    net, change, image = _network(tmp_path, steps=50)
    lut = calibrate_lut([change], [change[..., 0]], [change[..., 1]],
                        [np.ones(change.shape[:2], bool)], bins=8)
    lut.net = net
    p = lut.save(tmp_path / "lut.npz")
    meta = json.loads(p.with_suffix(".json").read_text())
    assert meta["gradient_model"] == "mlp" and meta["mlp_file"] == "lut.mlp.npz"
    back = PhotometricLUT.load(p)
    assert back.net is not None
    np.testing.assert_array_equal(back.lookup(change, image)[0], lut.lookup(change, image)[0])
    np.testing.assert_array_equal(back.lookup(change)[0], lut.lookup(change)[0])  # the table
    net_path(p).unlink()
    with pytest.raises(CalibrationError, match="lut.mlp.npz"):
        PhotometricLUT.load(p)
    # a path elsewhere, nothing, the directory itself or its parent, a NUL byte, a name longer
    # than a file system takes, not a string: one error naming the JSON and the field
    for name in ("../elsewhere.npz", "", ".", "..", "lut.mlp.npz\x00x", "a" * 5000, 5, None):
        meta["mlp_file"] = name
        p.with_suffix(".json").write_text(json.dumps(meta))
        with pytest.raises(CalibrationError, match=r"lut\.json: mlp_file .* beside"):
            PhotometricLUT.load(p)
    meta["gradient_model"] = "pickle"
    p.with_suffix(".json").write_text(json.dumps(meta))
    with pytest.raises(CalibrationError, match="gradient_model"):
        PhotometricLUT.load(p)


def test_vendored_real_presses_figures_and_report():
    """The vendored real GelSight presses (Taxim, MIT; 8 presses, even calibrate / odd test),
    annotation-free, through the interpreter: the figures docs/tactile.md reports."""
    from pathlib import Path

    from thintact_sdk.tactile.calibration.press_pack import evaluate_pack, load_press_pack

    path = Path(__file__).resolve().parents[2] / "thintact_sdk" / "data" / "gelsight" / \
        "gelsight_ball_presses.npz"
    pack = load_press_pack(path)
    res = evaluate_pack(pack, 2.0, 0.1245, model="auto")
    s = res["summary"]
    assert res["gradient_model"] == "lut" and res["validation"] is None  # 4 presses: no choice
    assert res["test"] == [1, 3, 5, 7] and s["presses"] == 4
    # measured (rigid cap, 4 presses: too few to choose the ball model; its depth bound
    # 0.95 R): depth RMS 0.128 mm and slope RMS 0.402 (flat 0.905, under 45 degrees
    # 0.348) inside the contact, sphere radius 2.05 mm, contact ratio 1.07 with the
    # contact grown by the calibration's 0.166 mm rim, 0.98 without (the region deeper than
    # 0.1 mm: 1.61)
    assert res["lut"].meta["ball_model"]["model"] == "rigid"
    assert 0.1 < res["lut"].meta["contact_rim_mm"] < 0.3
    assert s["depth_rms_mm"] < 0.15 and s["slope_rms"] < 0.45 < s["slope_rms_flat"]
    assert 1.9 < s["sphere_radius_median_mm"] < 2.3
    assert abs(s["contact_ratio_median"] - 1) < 0.1 < s["skirt_ratio_median"] - 1.3
    assert s["slope_rms_gentle"] < s["slope_rms"]
    # grown by the rim the calibration measured on its presses, the measure reads the taught
    # cap (rigid, smoothed by the 0.25 mm elastomer and the colour's pixel) about right
    assert abs(s["contact_ratio_taught_median"] - 1) < 0.05
    # every press's circle is wider than a 2 mm ball allows: the report says so
    assert all(any("not physical" in w for w in e["warnings"]) for e in res["press_report"])
    assert s["annotated_depth_rms_mm"] > 3 * s["depth_rms_mm"]  # the annotation's depth ≈ R


def test_vendored_real_presses_read_better_with_the_convolutional_network():
    """The same split with the convolutional network forced (short training, to keep the
    default suite fast): the steep flanks a per-pixel model reads short come back."""
    from pathlib import Path

    from thintact_sdk.tactile.calibration.press_pack import evaluate_pack, load_press_pack
    from thintact_sdk.tactile.interpretation.gradient_model import ConvGradient

    path = Path(__file__).resolve().parents[2] / "thintact_sdk" / "data" / "gelsight" / \
        "gelsight_ball_presses.npz"
    res = evaluate_pack(load_press_pack(path), 2.0, 0.1245, model="cnn",
                        cnn_options={"steps": 600})
    s = res["summary"]
    assert res["gradient_model"] == "cnn" and isinstance(res["lut"].net, ConvGradient)
    # measured (600 steps, crops weighted to cover the edge alike): depth RMS 0.091 mm, slope
    # RMS 0.276, against 0.128 mm and 0.402 for the table above; with the default 3000 steps
    # 0.057 mm and 0.199
    assert s["depth_rms_mm"] < 0.10 and s["slope_rms"] < 0.33


def test_edge_press_reads_as_deep_as_an_interior_one():
    """A simulated ball press whose contact crosses the frame's edge keeps its depth through
    the interpreter (free boundary); pinning the border to 0 loses it."""
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.calibration.ball_press import scene_level_lut
    from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
    from thintact_sdk.tactile.simulation.indenters import Sphere
    from thintact_sdk.tactile.simulation.membrane import TactileSimulator

    profile = load_profile("virtual-finger")
    sim = TactileSimulator.for_profile(profile)
    lut = scene_level_lut(profile)
    half_w = sim.params.cols / 2 * sim.params.mm_per_px
    peaks = {}
    for boundary in ("free", "zero"):
        interp = TactileInterpreter(profile, lut, boundary=boundary)
        interp.set_reference(sim.flat().scene)
        inner = interp.depth_from_image(sim.press(Sphere(2.0), 0.6, (0.0, 0.0)).scene)
        edge = interp.depth_from_image(sim.press(Sphere(2.0), 0.6, (half_w, 0.0)).scene)
        peaks[boundary] = float(edge.max()) / float(inner.max())
    # the ball's centre on the frame's edge (half the cap outside): measured 0.998 and 0.25
    # (0.86 and 0.61 while the simulator's elastomer blur read zeros past the frame's edge)
    assert peaks["free"] > 0.97
    assert peaks["zero"] < 0.5


def test_network_on_another_grid_is_refused_when_the_interpreter_is_built(tmp_path):
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter

    net, change, _ = _network(tmp_path, steps=5)
    lut = calibrate_lut([change], [change[..., 0]], [change[..., 1]],
                        [np.ones(change.shape[:2], bool)], bins=4)
    lut.net = net
    with pytest.raises(CalibrationError, match="calibrate-tactile"):
        TactileInterpreter(load_profile("virtual-finger"), lut)
