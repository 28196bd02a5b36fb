"""diagnose-tactile on simulated presses with tactile effects concealed at known strengths."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.diagnosis.tactile import TactileDiagnosisOptions, diagnose_tactile
from thintact_sdk.diagnosis.tactile.press_model import Press, TactileModel, ball_normals
from thintact_sdk.tactile.learning.domains import RealPresses

SHAPE = (60, 80)
MM_PER_PX = 0.1245
BALL_MM = 1.0
SIGMA = 0.01
LIGHT = np.array([[0.55, 0.0, 0.25], [-0.3, 0.45, 0.25], [-0.3, -0.45, 0.25]])
EFFECTS = ("illumination_field", "led_directions", "specular_lobe", "elastomer_blur",
           "camera_gamma")


def truth_model(**kw: object) -> TactileModel:
    m = TactileModel(field_coef=np.array([[0.5, 0.05, 0.02], [0.45, -0.04, 0.0],
                                          [0.5, 0.0, 0.05]]), light=LIGHT.copy())
    for k, v in kw.items():
        setattr(m, k, v)
    return m


def synthetic(model: TactileModel, n: int = 8, seed: int = 0) -> RealPresses:
    rng = np.random.default_rng(seed)
    r_px = BALL_MM / MM_PER_PX
    basis = np.stack([np.ones(SHAPE), *np.meshgrid(np.linspace(-1, 1, SHAPE[1]),
                                                   np.linspace(-1, 1, SHAPE[0]))[::-1]])
    basis = basis[[0, 2, 1]]  # 1, x, y as polynomial_basis orders them
    bg = model.background(basis, np.zeros(SHAPE + (3,)))
    imgs = []
    for _ in range(n):
        p = Press(float(rng.uniform(r_px, SHAPE[0] - r_px)),
                  float(rng.uniform(r_px, SHAPE[1] - r_px)), float(rng.uniform(0.3, 0.7)))
        nrm = ball_normals(SHAPE, p, BALL_MM, MM_PER_PX, model.sigma_mm, model.skirt_mm)
        imgs.append(model.respond(bg * model.shading(nrm)))
    images = np.stack(imgs) + rng.normal(0, SIGMA, (n,) + SHAPE + (3,))
    ref = model.respond(bg) + rng.normal(0, SIGMA, SHAPE + (3,))
    return RealPresses(images.astype(np.float32), ref.astype(np.float32), "synthetic")


def run(model: TactileModel, effects: tuple[str, ...] = EFFECTS):
    return diagnose_tactile(synthetic(model), BALL_MM, MM_PER_PX,
                            options=TactileDiagnosisOptions(effects=effects))


def test_lights_field_and_blur_are_named_and_recovered() -> None:
    d = run(truth_model(sigma_mm=0.5))
    names = [f["effect"] for f in d.report["findings"]]
    assert {"illumination_field", "led_directions", "elastomer_blur"} <= set(names)
    assert "camera_gamma" not in names
    assert d.report["final"]["chi2_per_dof"] < 1.1 < d.report["baseline"]["chi2_per_dof"]
    assert abs(d.final.sigma_mm - 0.5) < 0.08
    # azimuths are recovered; the light strength trades against the press depth (a deeper
    # press under a weaker light shades alike), so only the direction is asserted
    az = np.degrees(np.arctan2(d.final.light[:, 1], d.final.light[:, 0]))
    np.testing.assert_allclose(az, np.degrees(np.arctan2(LIGHT[:, 1], LIGHT[:, 0])), atol=5)
    assert not d.report["unexplained"]["significant"]


def test_specular_lobe_below_the_per_pixel_noise_is_named_and_recovered() -> None:
    truth = truth_model(specular=np.array([0.015, 0.015, 0.015]), shininess=12.0)
    # the lobe's largest contribution to any pixel is below the per-pixel noise
    nrm = ball_normals(SHAPE, Press(30.0, 40.0, 0.7), BALL_MM, MM_PER_PX, truth.sigma_mm)
    lobe = 0.5 * truth.specular * truth.lobe(nrm)
    assert np.abs(lobe).max() < SIGMA
    d = run(truth, ("illumination_field", "led_directions", "specular_lobe"))
    names = [f["effect"] for f in d.report["findings"]]
    assert "specular_lobe" in names
    # recovered: the fitted lobe's contribution to a press matches the concealed one (strength
    # and shininess trade against each other, so their product over the press is compared)
    fitted = 0.5 * d.final.specular * d.final.lobe(nrm)
    assert np.sqrt(np.mean((fitted - lobe) ** 2)) < 0.6 * np.sqrt(np.mean(lobe**2))
    assert d.report["final"]["chi2_per_dof"] < 1.1


def test_nothing_concealed_names_nothing_beyond_the_truth() -> None:
    d = run(truth_model())
    names = {f["effect"] for f in d.report["findings"]}
    assert names <= {"illumination_field", "led_directions"}
    assert d.report["final"]["chi2_per_dof"] < 1.1


@pytest.mark.parametrize("gamma", [0.45])
def test_camera_gamma_is_named_and_recovered(gamma: float) -> None:
    d = run(truth_model(gamma=gamma), ("illumination_field", "led_directions", "camera_gamma"))
    assert "camera_gamma" in [f["effect"] for f in d.report["findings"]]
    assert abs(d.final.gamma - gamma) < 0.05


SPREAD_EFFECTS = EFFECTS + ("optical_spread",)


def test_optical_spread_is_told_from_the_surface_blur_and_recovered() -> None:
    """Light scattered in the gel blurs the shading, not the surface: the diagnosis names
    ``optical_spread`` (σ_o within 25 %) and leaves the surface's blur alone."""
    d = run(truth_model(spread_mm=0.5), SPREAD_EFFECTS)
    names = [f["effect"] for f in d.report["findings"]]
    assert "optical_spread" in names
    assert abs(d.final.spread_mm - 0.5) < 0.125
    assert abs(d.final.sigma_mm - 0.25) < 0.08  # the surface keeps the profile's blur
    assert d.report["final"]["chi2_per_dof"] < 1.1


def test_surface_blur_is_not_taken_for_optical_spread() -> None:
    d = run(truth_model(sigma_mm=0.5), SPREAD_EFFECTS)
    names = [f["effect"] for f in d.report["findings"]]
    assert "elastomer_blur" in names and "optical_spread" not in names
    assert abs(d.final.sigma_mm - 0.5) < 0.08


def test_fitted_section_keeps_the_optical_spread() -> None:
    from thintact_sdk.diagnosis.tactile.report import model_from_section, model_section

    m = truth_model(spread_mm=0.42, sigma_mm=0.3)
    back = model_from_section(model_section(m, MM_PER_PX, "test"))
    assert back.spread_mm == pytest.approx(0.42) and back.sigma_mm == pytest.approx(0.3)
    old = model_section(truth_model(), MM_PER_PX, "test")  # written before the effect existed
    assert "optical_spread_mm" not in old["tactile"]["simulation_effects"]
    assert model_from_section(old).spread_mm == 0.0


def test_gel_sink_in_is_named_and_its_skirt_recovered() -> None:
    """A gel that sinks in around the ball (a K₀ skirt outside the contact circle): named as
    ``gel_sink_in`` with its length within 25 %, not as a wider Gaussian of the surface."""
    d = run(truth_model(skirt_mm=0.6), EFFECTS + ("gel_sink_in",))
    names = [f["effect"] for f in d.report["findings"]]
    assert "gel_sink_in" in names
    assert abs(d.final.skirt_mm - 0.6) < 0.15
    assert d.report["final"]["chi2_per_dof"] < 1.1


def test_effects_option_adds_the_opt_in_effects_and_refuses_unknown_names(tmp_path, capsys) -> None:
    from thintact_sdk.apps.cli.commands.diagnose_tactile import _effects
    from thintact_sdk.apps.cli.main import main
    from thintact_sdk.diagnosis.tactile.press_engine import TactileDiagnosisOptions
    from thintact_sdk.diagnosis.tactile.vocabulary import DEFAULT_EFFECTS, VOCABULARY

    assert "gel_sink_in" in VOCABULARY and "gel_sink_in" not in TactileDiagnosisOptions().effects
    assert _effects("+gel_sink_in") == DEFAULT_EFFECTS + ("gel_sink_in",)
    assert _effects("led_directions,optical_spread") == ("led_directions", "optical_spread")
    assert main(["diagnose-tactile", str(tmp_path), "--out", str(tmp_path / "o"),
                 "--effects", "+sinkin"]) == 2
    assert "sinkin" in capsys.readouterr().err
