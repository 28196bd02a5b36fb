"""Scene-level tactile pipeline: indenters, simulation, markers, LUT, Poisson, interpreter."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from thintact_sdk.errors import CalibrationError, ThinTactError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.tactile import (
    BallPress,
    ChamferedPrism,
    CubeEdge,
    Cylinder,
    MarkerTracker,
    PhotometricLUT,
    Sphere,
    TactileInterpreter,
    TactileSimulator,
    Text,
    Texture,
    calibrate_from_presses,
    detect_markers,
    find_press_circle,
    integrate_gradients,
    make_indenter,
    mean_shear,
    random_ball_presses,
    scene_level_lut,
)
from thintact_sdk.tactile.interpretation.interpreter import colour_change


@pytest.fixture(scope="module")
def profile():
    return load_profile("virtual-finger")


@pytest.fixture(scope="module")
def sim(profile):
    return TactileSimulator.for_profile(profile)


@pytest.fixture(scope="module")
def lut(profile):
    return scene_level_lut(profile)


def _depth_rms(frame_depth: np.ndarray, true_depth: np.ndarray) -> float:
    m = true_depth > 0.1
    return float(np.sqrt(np.mean((frame_depth - true_depth)[m] ** 2)))


def test_sphere_gap_is_the_ball_cap():
    s = Sphere(2.0)
    u = np.array([0.0, 1.0, 1.9, 2.5])
    gap = s.gap_mm(u, np.zeros_like(u))
    np.testing.assert_allclose(gap[:3], 2.0 - np.sqrt(4.0 - u[:3] ** 2))
    assert np.isinf(gap[3])


def test_rotation_turns_the_prism(profile, sim):
    x, y = sim.params.grid_mm()
    prism = ChamferedPrism(length_mm=6.0, width_mm=3.0, chamfer_mm=0.5)
    a = prism.indentation_mm(x, y, 0.5, (0.0, 0.0), 0.0) > 0
    b = prism.indentation_mm(x, y, 0.5, (0.0, 0.0), 90.0) > 0
    # 0°: long along x; 90°: long along y
    assert np.ptp(np.nonzero(a)[1]) > np.ptp(np.nonzero(a)[0])
    assert np.ptp(np.nonzero(b)[0]) > np.ptp(np.nonzero(b)[1])


@pytest.mark.parametrize(
    "indenter", [Cylinder(), CubeEdge(), Texture(), Text("AB", height_mm=3.0)], ids=lambda i: i.name
)
def test_every_indenter_makes_a_bounded_scene(sim, indenter):
    s = sim.press(indenter, 0.5, (0.5, -0.5), 20.0)
    assert s.scene.shape == (sim.params.rows, sim.params.cols, 3)
    assert s.scene.dtype == np.float32
    assert 0.0 <= s.scene.min() and s.scene.max() <= 1.0
    assert 0.05 < s.depth_mm.max() <= 0.5 + 1e-6


def test_unknown_indenter_is_refused():
    with pytest.raises(ThinTactError, match="unknown indenter"):
        make_indenter("banana")


def test_poisson_recovers_a_bump():
    mm = 0.1
    y, x = np.mgrid[0:100, 0:120] * mm
    d = 0.8 * np.exp(-((x - 6) ** 2 + (y - 5) ** 2) / (2 * 1.2**2))
    gy, gx = np.gradient(d, mm)
    rec = integrate_gradients(gx, gy, mm)
    assert float(np.sqrt(np.mean((rec - d) ** 2))) < 0.005


@pytest.mark.parametrize("shape, factor", [((400, 512, 3), 4), ((403, 517, 3), 4), ((37, 50), 3),
                                           ((20, 24, 7), 2), ((5, 6, 3), 8)])
def test_bin_image_is_the_block_mean(shape, factor):
    from thintact_sdk.tactile.interpretation.grid import bin_image

    a = np.random.default_rng(1).random(shape)
    n, m = shape[0] // factor, shape[1] // factor
    blocks = a[: n * factor, : m * factor].reshape((n, factor, m, factor) + shape[2:])
    got = bin_image(a, factor)
    assert got.dtype == np.float32 and got.shape == (n, m) + shape[2:]
    np.testing.assert_allclose(got, blocks.mean(axis=(1, 3)), rtol=0, atol=1e-6)


def test_lut_lookup_is_trilinear_in_the_table(lut):
    f = np.random.default_rng(2).normal(0, 0.05, (40, 3))
    t = lut._coords(f)
    i0 = t.astype(int)
    fr = t - i0
    expected = np.zeros((len(f), 2))
    for corner in np.ndindex(2, 2, 2):
        w = np.prod([fr[:, k] if c else 1 - fr[:, k] for k, c in enumerate(corner)], axis=0)
        expected += w[:, None] * lut.table[i0[:, 0] + corner[0], i0[:, 1] + corner[1], i0[:, 2] + corner[2]]
    gx, gy = lut.lookup(f)
    np.testing.assert_allclose(np.stack([gx, gy], axis=1), expected, rtol=0, atol=1e-6)


def test_markers_are_found_where_drawn(sim):
    flat = sim.flat()
    det = detect_markers(flat.scene, sim.params)
    assert len(det.positions_mm) == len(flat.marker_reference_mm)
    dist, _ = cKDTree(flat.marker_reference_mm).query(det.positions_mm)
    assert dist.max() < 0.02


def test_tracker_cascades_beyond_one_step_and_survives_losses():
    ref = np.stack(np.meshgrid(np.arange(5) * 1.5, np.arange(4) * 1.5), -1).reshape(-1, 2)
    tr = MarkerTracker(max_step_mm=0.6)
    tr.reset(ref)
    shift = np.zeros(2)
    for step in range(6):  # 6 × 0.3 mm = 1.8 mm total, more than a pitch
        shift += (0.3, 0.0)
        det = ref + shift
        if step in (2, 3):  # markers 0..2 hidden for two frames
            det = det[3:]
        pos, disp = tr.update(det[::-1])  # detection order must not matter
        if step in (2, 3):
            assert np.isnan(pos[:3]).all()
    np.testing.assert_allclose(disp, np.tile(shift, (len(ref), 1)), atol=1e-6)


def test_mean_shear_direction():
    d = np.zeros((20, 2))
    d[:5] = (0.0, -0.3)
    d[5, :] = np.nan
    _, direction = mean_shear(d)
    assert direction == pytest.approx(-np.pi / 2)
    assert np.isnan(mean_shear(np.zeros((4, 2)))[1])


@pytest.mark.parametrize("indenter", [Sphere(2.0), ChamferedPrism()], ids=lambda i: i.name)
@pytest.mark.parametrize("depth", [0.25, 1.0])
def test_depth_from_simulated_press(profile, sim, lut, indenter, depth):
    interp = TactileInterpreter(profile, lut)
    interp.set_reference(sim.flat().scene)
    s = sim.press(indenter, depth, (1.0, -0.5), 30.0)
    frame = interp.interpret(s.scene, timestamp_ns=5, frame_id=7)
    assert frame.depth_mm.shape == s.depth_mm.shape
    assert _depth_rms(frame.depth_mm, s.depth_mm) < 0.06
    assert frame.contact
    # the true contact: where the rigid indenter reaches the membrane. The contact region
    # is the part of the region deeper than the threshold where the membrane is concave.
    # The simulator's membrane is the indentation blurred by the elastomer Gaussian, which
    # rounds the rim inside the contact too; measured: sphere 0.47 of the true area at
    # 0.25 mm (all of the region deeper than 0.1 mm), 0.71-0.74 at 0.5-1 mm; prism 0.69-0.87
    x, y = sim.params.grid_mm()
    rigid = indenter.indentation_mm(x, y, depth, (1.0, -0.5), 30.0)
    true_area = float((rigid > 0).sum()) * sim.params.mm_per_px**2
    deeper = float((frame.depth_mm > 0.1).sum()) * sim.params.mm_per_px**2
    assert 0.4 * true_area < frame.contact_area_mm2 <= deeper + 1e-9
    assert (frame.timestamp_ns, frame.frame_id) == (5, 7)


def test_no_contact_frame(profile, sim, lut):
    interp = TactileInterpreter(profile, lut)
    flat = sim.flat().scene
    first = interp.interpret(flat)  # becomes the reference
    again = interp.interpret(flat)
    assert not first.contact and not again.contact
    assert float(again.depth_mm.max()) < 0.02
    assert np.nanmax(np.abs(again.marker_displacements_mm)) < 1e-3


def test_shear_is_tracked(profile, sim, lut):
    interp = TactileInterpreter(profile, lut)
    interp.set_reference(sim.flat().scene)
    s = sim.press(Sphere(2.0), 0.6, (0.0, 0.0), 0.0, shear_mm=(0.0, 0.3))
    frame = interp.interpret(s.scene)
    _, j = cKDTree(s.marker_reference_mm).query(interp.reference_markers_mm)
    ok = np.isfinite(frame.marker_displacements_mm[:, 0])
    assert ok.mean() > 0.9
    err = frame.marker_displacements_mm[ok] - s.marker_displacements_mm[j][ok]
    assert float(np.sqrt(np.mean(err**2))) < 0.02
    assert frame.shear_direction_rad == pytest.approx(np.pi / 2, abs=0.2)


def test_ball_model_calibration_without_simulator_slopes(profile, sim):
    """The real-device path: only the ball radius and the images are known."""
    data = random_ball_presses(profile, count=8, seed=3)
    ref = sim.flat().scene
    change = data[0][0].scene - ref
    (row, col), radius_px = find_press_circle(change)
    want = sim.params.mm_to_px(np.array([[data[0][1]["x_mm"], data[0][1]["y_mm"]]]))[0]
    assert np.hypot(row - want[0], col - want[1]) < 1.5
    lut = calibrate_from_presses(profile, ref, [BallPress(s.scene) for s, _ in data])
    assert lut.meta["slopes_from"] == "ball model"
    test = sim.press(Sphere(2.0), 0.75, (-1.0, 1.0))
    gx, gy = lut.lookup(colour_change(test.scene, ref, None, 1.0, 1.0))
    inside = test.depth_mm > 0.2
    err = np.hypot(gx - test.grad_x, gy - test.grad_y)[inside]
    scale = np.hypot(test.grad_x, test.grad_y)[inside]
    # smoothed-cap fit + one refinement round: about 0.22 of the slope scale remains
    assert float(np.sqrt(np.mean(err**2))) < 0.35 * float(np.sqrt(np.mean(scale**2)))


def test_lut_round_trip(tmp_path: Path, lut):
    p = lut.save(tmp_path / "lut.npz")
    back = PhotometricLUT.load(p)
    np.testing.assert_array_equal(back.table, lut.table)
    assert back.meta["profile"] == "virtual-finger"
    f = np.random.default_rng(0).normal(0, 0.05, (10, 3))
    np.testing.assert_allclose(back.lookup(f)[0], lut.lookup(f)[0])
    (tmp_path / "lut.json").write_text('{"format": "something-else"}')
    with pytest.raises(CalibrationError, match="format"):
        PhotometricLUT.load(p)
    with pytest.raises(CalibrationError, match="not found"):
        PhotometricLUT.load(tmp_path / "missing.npz")


def test_wrong_image_size_is_a_clear_error(profile, lut):
    interp = TactileInterpreter(profile, lut)
    with pytest.raises(ThinTactError, match="expects 100×128×3"):
        interp.interpret(np.zeros((10, 10, 3), np.float32))


def test_fine_grids_are_processed_binned_and_returned_full(profile):
    from thintact_sdk.formats.profiles import SceneSpec, TactileConfig

    fine = profile.model_copy(
        update={
            "name": "tac-fine-grid",
            "scene": SceneSpec(rows=200, cols=256, pixel_pitch_um=63.0),
            "tactile": TactileConfig(mm_per_px=0.063),
        },
        deep=True,
    )
    sim = TactileSimulator.for_profile(fine)
    interp = TactileInterpreter.for_profile(fine)  # no stored LUT: simulated one
    assert interp.factor == 2 and interp.work.rows == 100
    interp.set_reference(sim.flat().scene)
    s = sim.press(Sphere(2.0), 0.5, (-1.0, 0.5))
    frame = interp.interpret(s.scene)
    assert frame.depth_mm.shape == (200, 256)
    assert _depth_rms(frame.depth_mm, s.depth_mm) < 0.06


def test_a_stored_lut_for_another_grid_is_refused(tmp_path, monkeypatch, profile, lut):
    from thintact_sdk.formats.profiles import SceneSpec, TactileConfig
    from thintact_sdk.tactile import load_device_lut, save_device_lut

    monkeypatch.setenv("THINTACT_CALIBRATION_PATH", str(tmp_path))
    save_device_lut(lut, profile)
    assert load_device_lut(profile) is not None
    coarse = profile.model_copy(update={"scene": SceneSpec(rows=50, cols=64, pixel_pitch_um=252.0),
                                        "tactile": TactileConfig(mm_per_px=0.252)}, deep=True)
    with pytest.raises(CalibrationError, match="calibrate-tactile"):
        load_device_lut(coarse)


def test_reference_is_the_mean_of_the_first_frames(profile, sim, lut):
    rng = np.random.default_rng(0)
    flat = sim.flat().scene
    interp = TactileInterpreter(profile, lut, reference_frames=4)
    noisy = [flat + rng.normal(0, 0.03, flat.shape).astype(np.float32) for _ in range(4)]
    for img in noisy:
        interp.interpret(img)
    from thintact_sdk.tactile.interpretation.grid import bin_image

    expected = bin_image(np.mean(noisy, axis=0), interp.factor)
    membrane = bin_image(flat, interp.factor).min(axis=2) > 0.45  # markers are filled in
    same = np.abs(interp.background - expected)[membrane].max(axis=1) < 1e-5
    assert same.mean() > 0.8  # the rest are marker rims, filled in too
    before = interp.background.copy()
    interp.interpret(noisy[0])  # accumulation is over: the reference stays
    np.testing.assert_array_equal(interp.background, before)
