"""Force and slip: the elastic truth against closed forms, the estimators against the truth."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.frames import TactileFrame
from thintact_sdk.tactile import Sphere, TactileInterpreter, TactileSimulator, scene_level_lut
from thintact_sdk.tactile.interpretation.force import ForceModel, fit_gain
from thintact_sdk.tactile.interpretation.grid import pixel_grid_mm
from thintact_sdk.tactile.interpretation.slip import estimate_slip_ratio
from thintact_sdk.tactile.simulation.elastic import (
    Elastomer,
    solve_normal_contact,
    tangential_displacement,
)
from thintact_sdk.tactile.simulation.loaded_press import simulate_loaded_press

EL = Elastomer(youngs_mpa=0.3, poisson=0.48)
PX = 0.06
R = 4.0


def _interference(d):
    x, y = pixel_grid_mm(120, 120, PX)
    return d - Sphere(R).gap_mm(x, y)


def test_normal_contact_matches_hertz():
    for d in (0.2, 0.5):
        c = solve_normal_contact(_interference(d), PX, EL)
        hertz = 4 / 3 * EL.contact_modulus_mpa * np.sqrt(R) * d**1.5
        assert c.force_n == pytest.approx(hertz, rel=0.03)
        assert c.area_mm2 == pytest.approx(np.pi * R * d, rel=0.06)
        assert (c.pressure_mpa >= 0).all()


def test_cattaneo_mindlin_stick_zone_moves_rigidly_by_the_analytic_amount():
    d, d_stick, mu = 0.5, 0.25, 1.0
    full = solve_normal_contact(_interference(d), PX, EL)
    stick = solve_normal_contact(_interference(d_stick), PX, EL)
    q = mu * (full.pressure_mpa - stick.pressure_mpa)
    ux, uy = tangential_displacement(q, np.zeros_like(q), PX, EL)
    load_ratio = q.sum() * PX**2 / (mu * full.force_n)
    a, g, nu = np.sqrt(R * d), EL.shear_modulus_mpa, EL.poisson
    delta = 3 * mu * full.force_n * (2 - nu) / (16 * g * a) * (1 - (1 - load_ratio) ** (2 / 3))
    inner = ux[stick.contact]
    assert inner.mean() == pytest.approx(delta, rel=0.04)
    assert inner.std() < 0.01 * inner.mean()
    assert np.abs(uy[stick.contact]).max() < 1e-3 * inner.mean()
    ring = full.contact & ~stick.contact
    assert ux[ring].max() < inner.mean()  # the slip annulus lags the stuck centre


@pytest.fixture(scope="module")
def finger():
    profile = load_profile("virtual-finger")
    return profile, TactileSimulator.for_profile(profile), scene_level_lut(profile)


def _interpret(finger, press):
    profile, sim, lut = finger
    interp = TactileInterpreter(profile, lut)
    interp.set_reference(sim.flat().scene)
    return interp.interpret(press.scene.scene)


def test_frames_carry_force_and_slip_near_the_elastic_truth(finger):
    _, sim, _ = finger
    press = simulate_loaded_press(sim, EL, Sphere(5.0), 0.7, (0.5, -0.4), 0.0,
                                  shear_direction_rad=np.deg2rad(30), stick_fraction=0.6)
    frame = _interpret(finger, press)
    assert frame.force_n.shape == (3,)
    assert frame.force_n[2] == pytest.approx(press.force_n[2], rel=0.15)
    shear_true, shear_est = np.hypot(*press.force_n[:2]), np.hypot(*frame.force_n[:2])
    assert shear_est == pytest.approx(shear_true, rel=0.3)
    ang = np.arctan2(frame.force_n[1], frame.force_n[0])
    assert abs(np.rad2deg(ang) - 30.0) < 15.0
    assert 0.0 < frame.slip_ratio <= 1.0


def test_slip_ratio_rises_from_stick_to_sliding(finger):
    _, sim, _ = finger
    ratios = []
    for stick in (1.0, 0.7, 0.05):
        press = simulate_loaded_press(sim, EL, Sphere(8.0), 0.8, (0.0, 0.0), 0.0, 0.0, stick)
        ratios.append(_interpret(finger, press).slip_ratio)
    assert ratios[0] == 0.0
    assert ratios[0] < ratios[1] < ratios[2]
    assert ratios[2] > 0.5


def test_no_contact_means_no_force_and_no_slip(finger):
    _, sim, _ = finger
    frame = _interpret(finger, type("P", (), {"scene": sim.flat()})())
    assert not frame.contact
    np.testing.assert_array_equal(frame.force_n, np.zeros(3))
    assert frame.slip_ratio is None
    assert estimate_slip_ratio(np.zeros((20, 20)), 0.1, 0.1, np.zeros((0, 2)),
                               np.zeros((0, 2))) is None


def test_marker_free_gel_has_normal_force_and_unknown_shear():
    depth = np.zeros((60, 60))
    depth[25:35, 25:35] = 0.5
    f = ForceModel(EL).estimate(depth, 0.1, 0.1, np.zeros((0, 2)), np.zeros((0, 2)))
    assert f[2] > 0 and np.isnan(f[:2]).all()


def test_fit_gain_and_frame_defaults():
    assert fit_gain([1.0, 2.0], [2.0, 4.0]) == pytest.approx(2.0)
    frame = TactileFrame(np.zeros((2, 2, 3)), np.zeros((2, 2)), np.zeros((0, 2)),
                         np.zeros((0, 2)), False, 0.0, 0, 0)
    assert frame.force_n is None and frame.slip_ratio is None


@pytest.mark.slow
def test_bench_force_slip_rows(capsys):
    from thintact_sdk.apps.benchmarks.tactile_accuracy import force_slip
    from thintact_sdk.apps.cli.main import build_parser

    args = build_parser().parse_args(["bench", "tactile", "--force-presses", "4"])
    out: dict = {}
    force_slip(args, out)
    fs = out["force_slip"]
    assert fs["presses"] == 4 and len(fs["rows"]) == 4
    assert fs["normal_rel_rms"] < 0.5
    assert "normal force: relative RMS error" in capsys.readouterr().out


def test_evaluation_refuses_a_field_too_small_for_its_presses():
    from thintact_sdk.errors import ThinTactError
    from thintact_sdk.tactile.simulation.loaded_press import evaluate_force_slip

    with pytest.raises(ThinTactError, match="use virtual-finger"):
        evaluate_force_slip(load_profile("virtual-mini"), presses=2)


def test_a_pointed_contact_is_clamped_to_the_paraboloid_shape_constant():
    from thintact_sdk.tactile.interpretation.force import loaded_core

    yy, xx = np.mgrid[-30:30, -30:30] * 0.1
    cone = np.clip(0.6 - 0.3 * np.hypot(xx, yy), 0.0, None)  # fill ratio ≈ 1/3
    core = loaded_core(cone, 0.1, 0.1)
    assert core.fill < 0.45
    model = ForceModel(EL)
    base, filled = model.normal_features(core)
    assert filled == pytest.approx(0.5 * base)
    f = model.estimate(cone, 0.1, 0.1, np.zeros((0, 2)), np.zeros((0, 2)))
    assert f[2] == pytest.approx((model.normal_gain + 0.5 * model.normal_fill_gain) * base)
    assert f[2] > 0
