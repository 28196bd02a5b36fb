"""Proof on concealed effects: recordings rendered by ``tools/make_concealed_dataset.py``
(simulator with effects + noise model, profile with empty physics) must be diagnosed
correctly: the hidden effect named and its parameters recovered within the tolerances
below, nothing reported on clean data, defects flagged where they are.

The default run takes a handful of representative cases; the full matrix is marked slow.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

#: absolute tolerance per (effect, parameter) on the recovered value
TOLERANCE: dict[tuple[str, str], float] = {
    ("diffraction", "wavelength_nm"): 15.0,
    ("pixel_angular_response", "exponent"): 0.3,
    ("refraction", "n_scene_side"): 0.01,
    ("mask_misalignment", "angle_deg"): 0.05,
    ("mask_misalignment", "dx_um"): 1.5,
    ("mask_misalignment", "dy_um"): 1.5,
    ("mask_leakage", "transmittance"): 0.003,
    ("geometry", "scene_to_mask_mm"): 0.06,
    ("geometry", "mask_to_sensor_mm"): 0.015,
    ("sensor_gamma", "gamma"): 0.01,
    ("saturation", "level_dn"): 2.0,
    ("sensor_blur", "sigma_um"): 1.0,
    ("scene_blur", "sigma_um"): 3.0,
    ("display_gamma", "gamma"): 0.02,
    ("color_crosstalk", "matrix"): 0.005,
    ("veiling_glare", "fraction"): 0.003,
    ("stray_light", "mean_dn"): 3.0,
}


def param_errors(effect: str, got: dict[str, Any], want: dict[str, Any], scale: float = 1.0) -> list[str]:
    """Parameters of ``got`` outside the tolerance of ``want`` (messages)."""
    bad = []
    for name, value in want.items():
        tol = TOLERANCE[(effect, name)] * scale
        g = np.asarray(got[name], float)
        w = np.asarray(value, float)
        if g.shape != w.shape or np.any(np.abs(g - w) > tol):
            bad.append(f"{effect}.{name}: got {got[name]}, want {value} ± {tol}")
    return bad


def check_case(report: dict[str, Any], truth: dict[str, Any]) -> list[str]:
    """Everything wrong with a report given the case's truth (empty list: correct)."""
    problems = []
    hidden = truth["physics"]
    found = {f["effect"]: f for f in report["findings"]}
    named = set(found) | {a for f in report["findings"] for a in f["alternatives"]}
    for effect, params in hidden.items():
        if effect not in named:
            problems.append(f"{effect} hidden but not named (findings {sorted(found)})")
        elif effect in found:
            problems += param_errors(effect, found[effect]["params"], params, 2.0 if len(hidden) > 1 else 1.0)
    extra = set(found) - set(hidden) - {a for f in report["findings"] if f["effect"] in hidden for a in f["alternatives"]}
    # an effect the hidden one can be traded for (named as its alternative) is not extra
    extra -= {f["effect"] for f in report["findings"] if set(f["alternatives"]) & set(hidden)}
    if extra:
        problems.append(f"reported effects that were not hidden: {sorted(extra)}")
    defects = truth["defects"]
    un = report["unexplained"]
    if defects and not un["significant"]:
        problems.append("defect not flagged")
    if not defects and un["significant"]:
        problems.append(f"unexplained residual flagged on defect-free data: {un['summary']}")
    for dfc in defects:
        spots = un["hotspots"]
        if dfc["kind"] == "dust":
            hit = any(h["row0"] <= dfc["row"] < h["row1"] and h["col0"] <= dfc["col"] < h["col1"] for h in spots)
        else:
            hit = any(h["col0"] <= dfc["col"] < h["col1"] and h["col1"] - h["col0"] <= 3 for h in spots)
        if not hit:
            problems.append(f"defect {dfc} not located (hotspots {spots})")
    if abs(report["final"]["chi2_per_dof"] - 1.0) > 0.05 and not defects:
        problems.append(f"final chi2/dof {report['final']['chi2_per_dof']} not ≈ 1")
    return problems


def test_clean_recording_reports_nothing(concealed: Any) -> None:
    report, truth, _ = concealed("clean")
    assert report["findings"] == []
    assert report["unexplained"]["significant"] is False
    assert report["baseline"]["chi2_per_dof"] == pytest.approx(1.0, abs=0.02)
    assert report["final"]["chi2_per_dof"] == pytest.approx(1.0, abs=0.02)
    assert check_case(report, truth) == []


@pytest.mark.parametrize("case", ["mask_leakage", "subnoise_stray_light"])
def test_hidden_effect_named_and_fitted(concealed: Any, case: str) -> None:
    report, truth, _ = concealed(case)
    assert check_case(report, truth) == []
    assert report["final"]["chi2_per_dof"] < report["baseline"]["chi2_per_dof"]


def test_a_pixel_blur_beside_leakage_is_named_at_its_width(concealed: Any) -> None:
    """Issue 34: a 4 um sensor blur beside 2.5 % leakage, the blur rendered by scipy's Gaussian
    filter (sampled at the pixel offsets, as the independent renderer does). Both are named,
    the blur's σ within 25 % (it read 1.0 um when the simulator integrated the Gaussian over
    the pixels)."""
    report, truth, _ = concealed("pair_sensor_blur_leakage")
    assert check_case(report, truth) == []
    found = {f["effect"]: f for f in report["findings"]}
    assert set(found) == {"sensor_blur", "mask_leakage"}
    assert abs(found["sensor_blur"]["params"]["sigma_um"] - 4.0) < 1.0
    assert abs(found["mask_leakage"]["params"]["transmittance"] - 0.025) < 0.003


@pytest.mark.slow
def test_a_pixel_blur_under_a_raised_floor_is_named(concealed: Any, concealed_case: Any) -> None:
    """With the amplitude floor set above the blur's change of the prediction (as the
    independent renderer's recording had it), the blur is still named: its fit is decisive
    and stable under refit on each half of the frames, and its amplitude is stated (a second
    diagnosis of the case: slow; test_diagnose_unbinned covers the rule in the default run)."""
    from thintact_sdk.diagnosis.imaging import DiagnoseOptions, diagnose, load_diagnosis_data

    _, _, d = concealed("pair_sensor_blur_leakage")
    blur = next(r for r in d.selection.rounds if r.name == "sensor_blur")
    sig = d.selection.evaluation.pred_dn - 64.0
    fraction = blur.amplitude_dn / float(np.sqrt(np.mean(sig**2)))
    high = diagnose(load_diagnosis_data(concealed_case("pair_sensor_blur_leakage") / "recording"),
                    options=DiagnoseOptions(amp_floor=1.5 * fraction))
    named = {f["effect"]: f for f in high.report["findings"]}
    assert set(named) == {"sensor_blur", "mask_leakage"} and "below_floor" not in high.report
    f = named["sensor_blur"]
    assert abs(f["params"]["sigma_um"] - 4.0) < 1.0 and f["amplitude_fraction"] < 1.5 * fraction
    assert "stable under refit" in f["evidence"]
    assert all(abs(h["sigma_um"] - 4.0) < 1.0 for h in f["refit_on_halves"])


def test_subnoise_effect_is_below_the_pixel_noise(concealed: Any) -> None:
    """The sub-noise case really is invisible per pixel: the effect's rms is below the noise."""
    report, truth, _ = concealed("subnoise_stray_light")
    assert truth["effect_rms_dn"] < report["noise_rms_dn"]


def test_dust_speck_flagged_where_it_is(concealed: Any) -> None:
    report, truth, _ = concealed("dust")
    assert check_case(report, truth) == []
    assert report["findings"] == []


@pytest.mark.slow
@pytest.mark.parametrize(
    "case",
    [
        "diffraction", "pixel_angular_response",
        "refraction",
        "mask_misalignment", "mask_shift",
        "geometry", "sensor_gamma", "saturation", "sensor_blur", "scene_blur", "display_gamma",
        "color_crosstalk", "veiling_glare", "stray_light", "subnoise_leakage", "subnoise_sensor_blur",
        "subnoise_glare", "pair_gamma_stray", "pair_angular_leakage", "pair_diffraction_shift",
        "dim_column", "mask_rotation_035", "pair_rotation_refraction",
        "pair_rotation_diffraction", "triple_rotation_diffraction_stray",
        "triple_rotation_refraction_gamma", "pair_sensor_blur_leakage", "pair_sensor_blur_leakage_1pct",
    ],
)
def test_concealed_matrix(concealed: Any, case: str) -> None:
    report, truth, _ = concealed(case)
    assert check_case(report, truth) == []
