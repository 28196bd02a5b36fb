"""The diagnosis machinery on a toy forward model (no simulator needed): it must name the
effect hidden in the toy data, recover its parameter, and stay quiet on clean data."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from thintact_sdk.diagnosis.imaging.engine import DiagnoseOptions, diagnose
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData
from thintact_sdk.formats.profiles import load_profile

R, S, N, M = 48, 60, 12, 15


def toy_variance(pred_dn: np.ndarray, noise) -> np.ndarray:  # noqa: ANN001
    sig = np.maximum(pred_dn - noise.black_level_dn, 0.0)
    return noise.read_noise_dn**2 + sig / noise.electrons_per_dn + 1.0 / 12.0


def _toy_matrices() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    p = (rng.random((R, N)) > 0.5).astype(float) + 0.2
    q = (rng.random((S, M)) > 0.5).astype(float) + 0.2
    return p, q


P, Q = _toy_matrices()


def toy_simulate(profile, scenes: np.ndarray) -> np.ndarray:  # noqa: ANN001
    """Separable toy imaging with two optical 'effects': sensor blur and angular response."""
    out = np.einsum("rn,fnmc,sm->frsc", P, scenes, Q)
    phys = profile.physics
    if "pixel_angular_response" in phys:
        y = np.linspace(-1, 1, R)[:, None]
        x = np.linspace(-1, 1, S)[None, :]
        fac = (1.0 / (1.0 + 0.3 * (x * x + y * y))) ** (0.5 * phys["pixel_angular_response"]["exponent"])
        out = out * fac[None, :, :, None]
    for blur in ("sensor_blur", "scene_blur"):  # the toy makes the two indistinguishable
        if blur in phys:
            s = phys[blur]["sigma_um"] / profile.sensor.pixel_pitch_um
            if s > 0:
                out = ndimage.gaussian_filter(out, (0, s, s, 0), mode="nearest")
    return out


def _data(physics: dict, seed: int = 0, defect: bool = False) -> DiagnosisData:
    prof = load_profile("virtual-mini")
    prof.sensor.rows, prof.sensor.cols = R, S
    prof.scene.rows, prof.scene.cols = N, M
    rng = np.random.default_rng(seed)
    scenes = np.concatenate([np.ones((1, N, M, 3)), rng.random((7, N, M, 3))])
    irr = toy_simulate(prof.with_physics(physics), scenes)
    signal = irr * (2000.0 / irr[0].max()) * np.array([1.0, 0.9, 0.8])
    if defect:
        yy, xx = np.mgrid[0:R, 0:S]
        signal = signal * (1 - 0.4 * np.exp(-((yy - 30) ** 2 + (xx - 12) ** 2) / 4.0))[None, :, :, None]
    noise = prof.noise
    meas = rng.poisson(signal * noise.electrons_per_dn) / noise.electrons_per_dn
    meas = np.round(meas + noise.black_level_dn + rng.normal(0, noise.read_noise_dn, meas.shape))
    return DiagnosisData(prof.with_physics({}), [f"f{i}" for i in range(8)], scenes, meas)


OPTS = DiagnoseOptions(candidates=["sensor_blur", "pixel_angular_response", "stray_light", "veiling_glare"])


def test_toy_clean_data_gives_no_findings() -> None:
    d = diagnose(_data({}), toy_simulate, toy_variance, OPTS)
    rep = d.report
    assert rep["findings"] == []
    assert not rep["unexplained"]["significant"]
    assert rep["final"]["chi2_per_dof"] == pytest.approx(1.0, abs=0.03)


def test_toy_names_hidden_blur_and_recovers_sigma() -> None:
    d = diagnose(_data({"sensor_blur": {"sigma_um": 12.0}}), toy_simulate, toy_variance, OPTS)
    rep = d.report
    assert [f["effect"] for f in rep["findings"]] == ["sensor_blur"]
    assert rep["findings"][0]["params"]["sigma_um"] == pytest.approx(12.0, rel=0.05)
    assert rep["baseline"]["chi2_per_dof"] > 1.5
    assert rep["final"]["chi2_per_dof"] == pytest.approx(1.0, abs=0.03)
    assert d.fitted_profile.physics["sensor_blur"]["sigma_um"] == pytest.approx(12.0, rel=0.05)


def test_toy_flags_a_dark_spot_where_it_is() -> None:
    d = diagnose(_data({}, defect=True), toy_simulate, toy_variance, OPTS)
    un = d.report["unexplained"]
    assert un["significant"]
    h = un["hotspots"][0]
    assert h["row0"] <= 30 < h["row1"] and h["col0"] <= 12 < h["col1"]
    assert d.report["findings"] == []


def test_toy_names_an_indistinguishable_effect_as_alternative() -> None:
    opts = DiagnoseOptions(candidates=["sensor_blur", "scene_blur", "pixel_angular_response"])
    d = diagnose(_data({"sensor_blur": {"sigma_um": 12.0}}), toy_simulate, toy_variance, opts)
    f = d.report["findings"]
    assert len(f) == 1
    assert {f[0]["effect"], *f[0]["alternatives"]} == {"sensor_blur", "scene_blur"}
    assert "To tell" in f[0]["evidence"]


def test_toy_spent_time_budget_stops_the_selection_with_a_valid_report() -> None:
    opts = DiagnoseOptions(candidates=OPTS.candidates, time_budget_s=1e-9)
    d = diagnose(_data({"sensor_blur": {"sigma_um": 12.0}}), toy_simulate, toy_variance, opts)
    assert d.report["findings"] == []
    assert "time budget reached: selection stopped" in d.selection.log
    assert np.isfinite(d.report["final"]["chi2_per_dof"])
