"""Kernel effects (diffraction, angular response, refraction, misalignment, leakage, geometry)
against independent calculations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.simulator.sim_helpers import rel_rms, tiny_profile
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.simulation.effects import diffraction, refraction
from thintact_sdk.simulation.reference import reference_forward
from thintact_sdk.simulation.simulator import Simulator


@pytest.fixture(scope="module")
def mini():
    return load_profile("virtual-mini")


@pytest.fixture(scope="module")
def scenes():
    return np.random.default_rng(11).random((3, 50, 64, 3))


@pytest.fixture(scope="module")
def small(mini):
    """virtual-mini's pitches and mask on a quarter of its area (fast direct-path builds)."""
    p = mini.model_copy(deep=True)
    p.sensor.rows, p.sensor.cols, p.scene.rows, p.scene.cols = 64, 80, 25, 32
    return p


@pytest.fixture(scope="module")
def small_scenes():
    return np.random.default_rng(13).random((3, 25, 32, 3))


def _with_mask(profile, phi, phi_rows=None):
    p = profile.model_copy(deep=True)
    p.mask.phi = [int(v) for v in phi]
    p.mask.phi_rows = None if phi_rows is None else [int(v) for v in phi_rows]
    return p


def test_leakage_one_is_open_aperture(mini, scenes):
    y = Simulator(mini.with_physics({"mask_leakage": {"transmittance": 1.0}})).forward_batch(scenes)
    y_open = Simulator(_with_mask(mini, np.ones(mini.mask.K))).forward_batch(scenes)
    assert np.allclose(y, y_open, rtol=1e-10, atol=0)


def test_leakage_is_linear_in_t(mini, scenes):
    y0 = Simulator(mini).forward_batch(scenes)
    y1 = Simulator(mini.with_physics({"mask_leakage": {"transmittance": 1.0}})).forward_batch(scenes)
    yt = Simulator(mini.with_physics({"mask_leakage": {"transmittance": 0.2}})).forward_batch(scenes)
    assert np.allclose(yt, 0.8 * y0 + 0.2 * y1, rtol=1e-10)


def test_geometry_effect_equals_profile_geometry(mini, scenes):
    moved = mini.model_copy(deep=True)
    moved.geometry.scene_to_mask_mm = 4.5
    moved.geometry.mask_to_sensor_mm = 1.1
    ph = {"geometry": {"scene_to_mask_mm": 4.5, "mask_to_sensor_mm": 1.1}}
    assert np.array_equal(Simulator(mini.with_physics(ph)).forward_batch(scenes),
                          Simulator(moved).forward_batch(scenes))
    assert rel_rms(Simulator(moved).forward_batch(scenes), Simulator(mini).forward_batch(scenes)) > 1e-2


def test_angular_response_zero_is_identity(mini, scenes):
    y = Simulator(mini.with_physics({"pixel_angular_response": {"exponent": 0.0}}))
    assert np.allclose(y.forward_batch(scenes), Simulator(mini).forward_batch(scenes), rtol=1e-12)


def test_one_cell_shift_equals_rolled_phi(small, small_scenes):
    """The device only sees the central cells, so a shift by one cell (+x, +y) is φ rolled by one."""
    d = small.mask.feature_um
    shifted = small.with_physics({"mask_misalignment": {"dx_um": d, "dy_um": -d}})
    rolled = _with_mask(small, np.roll(small.mask.phi, 1), np.roll(small.mask.rows_vector, -1))
    y_roll = Simulator(rolled).forward_batch(small_scenes)
    assert np.allclose(Simulator(shifted).forward_batch(small_scenes), y_roll, rtol=1e-9)
    assert rel_rms(Simulator(shifted, direct=True).forward_batch(small_scenes), y_roll) < 1e-3


def test_direct_path_matches_separable(small, small_scenes):
    assert rel_rms(Simulator(small, direct=True).forward_batch(small_scenes),
                   Simulator(small).forward_batch(small_scenes)) < 1e-3


def test_rotation_small_angle_is_continuous(small, small_scenes):
    y0 = Simulator(small).forward_batch(small_scenes)
    rot = [Simulator(small.with_physics({"mask_misalignment": {"angle_deg": a}})).forward_batch(
        small_scenes) for a in (1e-4, 0.5)]
    assert rel_rms(rot[0], y0) < 1e-3 < rel_rms(rot[1], y0)


RAY_DEVICE = dict(rows=4, cols=5, scene_rows=3, scene_cols=4, pitch_um=20.0,
                  scene_pitch_um=60.0, feature_um=25.0, z_mm=1.0, d_mm=0.3)


@pytest.mark.parametrize("physics", [
    {"refraction": {"n_scene_side": 1.4}, "mask_misalignment": {"angle_deg": 3.0, "dx_um": 10.0}},
    {"refraction": {"n_scene_side": 1.4}},
])
def test_forced_direct_path_against_brute_force(physics):
    """The dense direct path (only with ``direct=True`` now: every effect has a separable
    kernel) stays within 1e-2; its pair-centre radiometry keeps it ~6e-3 off on this wide-angle
    device, where the separable kernels are within 1e-3
    (tests/simulator/test_sim_effects_bruteforce.py)."""
    prof = tiny_profile(physics, **RAY_DEVICE)
    assert Simulator(prof).separable
    sim = Simulator(prof, direct=True)
    assert not sim.separable
    x = np.random.default_rng(12).random((3, 4, 3))
    assert rel_rms(sim.forward(x), reference_forward(prof, x, 12, 12)) < 1e-2
    from thintact_sdk.errors import ThinTactError

    with pytest.raises(ThinTactError, match="not separable"):
        sim.separable_terms(0)


def test_refraction_index_one_is_identity(mini, scenes):
    sim = Simulator(mini.with_physics({"refraction": {"n_scene_side": 1.0}}))
    assert sim.separable
    assert np.allclose(sim.forward_batch(scenes), Simulator(mini).forward_batch(scenes), rtol=1e-12)
    kappa, factor = refraction.crossing_fraction_and_factor(np.array([0.0, 0.7, 3.0]), 4.8, 1.0, 1.0)
    h = 5.8
    assert np.allclose(kappa, 1.0 / h)
    assert np.allclose(factor, h**2 / (h**2 + np.array([0.0, 0.7, 3.0]) ** 2) ** 2)


def test_snell_ray_check():
    z, d, n = 4.8, 1.0, 1.45
    rho = np.array([0.0, 0.01, 0.5, 2.0, 6.0, 15.0])
    theta = refraction.solve_air_angle(rho, z, d, n)
    theta_m = np.arcsin(np.sin(theta) / n)
    assert np.allclose(np.sin(theta), n * np.sin(theta_m))
    assert np.allclose(d * np.tan(theta) + z * np.tan(theta_m), rho, atol=1e-12)
    kappa, _ = refraction.crossing_fraction_and_factor(rho, z, d, n)
    # the crossing point is where the air segment of the ray meets the mask plane
    assert np.allclose(kappa[1:] * rho[1:], d * np.tan(theta[1:]))
    assert kappa[0] == pytest.approx(d / (d + z / n))


def test_refraction_factor_conserves_flux():
    """Integrating the irradiance factor over the whole scene plane gives π/n² · ∫cos^(1+p)…:
    for p = 0, ∫ cosθ dΩ over the hemisphere of the air side that the medium can fill,
    i.e. π·(1/n²)·(n² sin²θc) = π with sinθc = 1 (every air direction is reached)."""
    z, d, n = 4.8, 1.0, 1.45
    rho = np.linspace(0, 4000.0, 400_001)
    _, factor = refraction.crossing_fraction_and_factor(rho, z, d, n)
    flux = np.trapezoid(factor * 2 * np.pi * rho, rho)
    assert flux * n**2 == pytest.approx(math.pi, rel=2e-3)


def test_diffraction_field_against_numerical_fresnel_integral():
    edges = np.array([-0.03, -0.01, 0.0, 0.02, 0.05])
    vals = np.array([[1.0, 0.0, 1.0, 1.0], [1.0, -1.0, 1.0, -1.0]])
    w = diffraction.fresnel_width_mm(530.0, 4.8, 1.0)
    m_star = np.array([-0.02, 0.001, 0.035])
    v = diffraction.axis_fields(edges, vals, m_star, w)
    m = np.linspace(edges[0], edges[-1], 400_001)
    cell = np.clip(np.searchsorted(edges, m, side="right") - 1, 0, 3)
    for k, ms in enumerate(m_star):
        kern = np.exp(1j * np.pi * (m - ms) ** 2 / w**2)
        num = np.trapezoid(vals[:, cell] * kern, m, axis=1) / (w * np.exp(1j * np.pi / 4))
        assert np.allclose(v[:, k], num, atol=1e-4)  # trapezoid error at the cell jumps
    wide = diffraction.axis_fields(np.array([-50.0, 50.0]), np.ones((1, 1)), np.array([0.0]), w)
    assert abs(wide[0, 0] - 1) < 1e-3


def test_a_wavelength_too_short_to_sample_is_refused(mini, scenes):
    """0.001 nm (inside the parameter's bounds) asked for 1e7 samples per axis and ran for
    minutes or ended in std::bad_alloc; it is geometric optics."""
    from thintact_sdk.errors import KernelSizeError

    with pytest.raises(KernelSizeError, match="at 0.001 nm .*geometric optics"):
        Simulator(mini.with_physics({"diffraction": {"wavelength_nm": [0.001] * 3}})).forward_batch(scenes)


def test_diffraction_tends_to_geometric(mini, scenes):
    y_geo = Simulator(mini).forward_batch(scenes)
    tiny_wave = Simulator(mini.with_physics({"diffraction": {"wavelength_nm": [5.0, 5.0, 5.0]}}))
    real = Simulator(mini.with_physics({"diffraction": {}}))
    e_tiny = rel_rms(tiny_wave.forward_batch(scenes), y_geo)
    e_real = rel_rms(real.forward_batch(scenes), y_geo)
    assert e_tiny < 5e-3 < e_real
    assert e_tiny < e_real / 5
    x = scenes[0]
    for c in range(3):
        terms = real.separable_terms(c)
        assert np.allclose(sum(p @ x[..., c] @ q.T for p, q in terms), real.forward(x)[..., c])


def test_diffraction_composes_with_refraction_but_not_the_forced_direct_path(mini):
    from thintact_sdk.errors import ThinTactError

    physics = {"diffraction": {}, "refraction": {"n_scene_side": 1.3},
               "mask_misalignment": {"angle_deg": 0.3}}
    with pytest.raises(ThinTactError, match="diffraction"):
        Simulator(mini.with_physics(physics), direct=True)
    assert Simulator(mini.with_physics(physics)).separable


def test_diffraction_pixel_pair_against_2d_fresnel_quadrature():
    """A tiny device (0.5 um pixels, 8-cell mask) against direct numerical quadrature of the
    2-D Fresnel integral over the mask, averaged over sample points of the sensor pixel and of
    the lit scene pixel (the mask is separable, so the 2-D integral is done as products of
    1-D quadratures of ½(1 + φ_r φ_c))."""
    k, feature, pitch = 8, 20.0, 0.5
    prof = tiny_profile({"diffraction": {"wavelength_nm": [530.0, 530.0, 530.0]}},
                        rows=5, cols=5, pitch_um=pitch, scene_rows=3, scene_cols=3,
                        scene_pitch_um=pitch, feature_um=feature, k=k, z_mm=0.3, d_mm=0.1, seed=4)
    x = np.zeros((3, 3, 3))
    x[2, 0, :] = 1.0  # scene pixel centred at (x, y) = (-0.5, +0.5) um
    y = Simulator(prof).forward(x)[..., 0]
    lam, z, d = 530e-6, 0.3, 0.1
    h, p_mm = z + d, pitch * 1e-3
    step = 0.05e-3
    m = (np.arange(int(k * feature * 1e-3 / step)) + 0.5) * step - k * feature * 1e-3 / 2
    cell = np.floor(m / (feature * 1e-3) + k / 2).astype(int)
    norm = step / np.sqrt(lam * z * d / h)  # unbounded open aperture → |field| = 1 per axis
    off_u = ((np.arange(8) + 0.5) / 8 - 0.5) * p_mm
    off_s = ((np.arange(4) + 0.5) / 4 - 0.5) * p_mm

    def axis(u_c, s_c, phi):
        uu = (u_c + off_u)[:, None, None]
        ss = (s_c + off_s)[None, :, None]
        e = np.exp(1j * np.pi / lam * ((m - ss) ** 2 / z + (uu - m) ** 2 / d))
        return (e.sum(-1) * norm).ravel(), ((e * phi[cell]).sum(-1) * norm).ravel(), (ss - uu).ravel()

    phi = np.asarray(prof.mask.phi, float)
    phi_r = np.asarray(prof.mask.rows_vector, float)
    for r, c in [(2, 2), (0, 4), (3, 1)]:
        ax, px, dx = axis((c - 2) * p_mm, -p_mm, phi)
        ay, py, dy = axis((r - 2) * p_mm, p_mm, phi_r)
        field = 0.5 * (np.outer(ay, ax) + np.outer(py, px))
        rad = h**2 / (h**2 + dx[None, :] ** 2 + dy[:, None] ** 2) ** 2
        want = float(np.mean(rad * np.abs(field) ** 2)) * p_mm**2
        assert y[r, c] == pytest.approx(want, rel=2e-3)


def test_windowed_fields_match_box_averaged_exact_fields():
    """Far-edge fringes replaced by their mean power: after averaging over a 10 um sensor
    pixel and a 31.5 um scene pixel (boxes of 8.3 and 5.4 um in the mask plane) the profiles
    equal those of the exact fields."""
    k = 96
    edges = (np.arange(k + 1) - k / 2) * 0.02
    phi = np.random.default_rng(5).choice([-1.0, 1.0], k)
    prof = np.stack([np.ones(k), phi])
    w = diffraction.fresnel_width_mm(530.0, 4.8, 1.0)
    h = 2e-5
    m = np.arange(-0.25, 0.25, h)
    exact = diffraction.axis_fields(edges, prof, m, w)
    (va, vp), tail = diffraction.axis_fields_local(edges, prof, m, w, reach_w=16.0)
    boxes = [np.full(int(0.0083 / h), 1 / int(0.0083 / h)), np.full(int(0.0054 / h), 1 / int(0.0054 / h))]

    def avg(v):
        return np.convolve(np.convolve(v, boxes[0], "same"), boxes[1], "same")[1000:-1000]

    pairs = [
        (np.abs(exact[0]) ** 2, np.abs(va) ** 2 + tail[0, 0]),
        (np.abs(exact[1]) ** 2, np.abs(vp) ** 2 + tail[1, 1]),
        ((exact[0] * np.conj(exact[1])).real, (va * np.conj(vp)).real + tail[0, 1]),
    ]
    for want, got in pairs:
        assert rel_rms(avg(got), avg(want)) < 2e-3


def test_lattice_fields_equal_the_windowed_fields():
    """Equal cells: the FFT correlation on the fine lattice gives the windowed fields and the
    dropped fringes' power of :func:`axis_fields_local` at the same points (a shifted mask,
    points beyond both ends included), and ``axis_intensity_profiles`` aligns its fine cells
    with the mask edges."""
    k, feature, shift = 64, 0.02, 0.0037
    phi = np.random.default_rng(7).choice([-1.0, 1.0], k)
    prof = np.stack([np.ones(k), phi])
    w = diffraction.fresnel_width_mm(530.0, 4.8, 1.0)
    e0, sub, k_lo, k_hi = -k / 2 * feature + shift, 50, -900, k * 50 + 700
    got, got_tail = diffraction.lattice_fields(e0, feature, prof, sub, k_lo, k_hi, w, reach_w=16.0)
    centres = e0 + (np.arange(k_lo, k_hi) + 0.5) * feature / sub
    edges = (np.arange(k + 1) - k / 2) * feature + shift
    want, want_tail = diffraction.axis_fields_local(edges, prof, centres, w, reach_w=16.0)
    assert np.max(np.abs(got - want)) < 1e-9
    assert np.max(np.abs(got_tail - want_tail)) < 1e-9
    fine, _ = diffraction.axis_intensity_profiles(edges, phi, -0.5, 0.5, 530.0, 4.8, 1.0)
    h = float(np.diff(fine).mean())
    assert fine[0] <= -0.5 and fine[-1] >= 0.5 and np.allclose(np.diff(fine), h)
    assert feature / h == pytest.approx(round(feature / h), abs=1e-9)  # whole cells
    assert ((fine[0] - edges[0]) / h) == pytest.approx(round((fine[0] - edges[0]) / h), abs=1e-6)


def test_diffraction_with_rotated_mask_against_2d_fresnel_quadrature():
    """Diffraction composes with a rotated, shifted mask: a tiny device against direct
    numerical quadrature of the 2-D Fresnel integral. Fresnel propagation is rotation-invariant,
    so in the pattern's frame the integral over the mask factorises into 1-D quadratures
    around p* = Rot(-θ)(m* - shift), m* = (z·u + d·s)/H, for every pair of sample points."""
    k, feature, pitch, angle, dx_um, dy_um = 8, 20.0, 0.5, 2.0, 4.0, -3.0
    prof = tiny_profile({"diffraction": {"wavelength_nm": [530.0, 530.0, 530.0]},
                         "mask_misalignment": {"angle_deg": angle, "dx_um": dx_um, "dy_um": dy_um}},
                        rows=5, cols=5, pitch_um=pitch, scene_rows=3, scene_cols=3,
                        scene_pitch_um=pitch, feature_um=feature, k=k, z_mm=0.3, d_mm=0.1, seed=4)
    x = np.zeros((3, 3, 3))
    x[2, 0, :] = 1.0  # scene pixel centred at (x, y) = (-0.5, +0.5) um
    y = Simulator(prof).forward(x)[..., 0]
    unrotated = Simulator(prof.with_physics({"diffraction": {"wavelength_nm": [530.0] * 3},
                                             "mask_misalignment": {"dx_um": dx_um, "dy_um": dy_um}}))
    lam, z, d = 530e-6, 0.3, 0.1
    h, p_mm = z + d, pitch * 1e-3
    w = math.sqrt(lam * z * d / h)
    step = 0.05e-3
    m = (np.arange(int(k * feature * 1e-3 / step)) + 0.5) * step - k * feature * 1e-3 / 2
    cell = np.floor(m / (feature * 1e-3) + k / 2).astype(int)
    phi = np.asarray(prof.mask.phi, float)
    phi_r = np.asarray(prof.mask.rows_vector, float)
    n_u, n_s = 6, 3
    off_u = ((np.arange(n_u) + 0.5) / n_u - 0.5) * p_mm
    off_s = ((np.arange(n_s) + 0.5) / n_s - 0.5) * p_mm
    a = math.radians(angle)

    def fields(p_star, prof_1d):
        e = np.exp(1j * np.pi * (m - p_star[..., None]) ** 2 / w**2) * step / w
        return e.sum(-1), (e * prof_1d[cell]).sum(-1)

    for r, c in [(2, 2), (0, 4), (3, 1)]:
        uy, ux = (r - 2) * p_mm + off_u[:, None, None, None], (c - 2) * p_mm + off_u[None, :, None, None]
        sy, sx = p_mm + off_s[None, None, :, None], -p_mm + off_s[None, None, None, :]
        mx, my = (z * ux + d * sx) / h - dx_um * 1e-3, (z * uy + d * sy) / h - dy_um * 1e-3
        px, py = math.cos(a) * mx + math.sin(a) * my, -math.sin(a) * mx + math.cos(a) * my
        ax, fx = fields(px, phi)
        ay, fy = fields(py, phi_r)
        field = 0.5 * (ax * ay + fx * fy)
        rad = h**2 / (h**2 + (sx - ux) ** 2 + (sy - uy) ** 2) ** 2
        want = float(np.mean(rad * np.abs(field) ** 2)) * p_mm**2
        assert y[r, c] == pytest.approx(want, rel=2e-3)
    assert rel_rms(unrotated.forward(x)[..., 0], y) > 2e-2


def test_refraction_on_a_paper_size_device_is_refused_with_a_message():
    """At 1024×1280 the Snell family would need ~1.4 TiB: a ThinTactError, not a MemoryError."""
    from thintact_sdk.errors import ThinTactError
    from thintact_sdk.formats.profiles import load_profile

    paper = load_profile("thintact-paper").with_physics({"refraction": {"n_scene_side": 1.41}})
    with pytest.raises(ThinTactError, match="refraction on this device needs"):
        Simulator(paper).kernel  # noqa: B018 - building the kernel is the test
