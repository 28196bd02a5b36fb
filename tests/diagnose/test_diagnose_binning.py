"""Sensor-binned diagnosis of large devices (issue 17, "Full-size recordings")."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from thintact_sdk.diagnosis.imaging.binning import (
    ScreeningLimits,
    auto_bin_factor,
    bin_frames,
    binned_profile,
    binned_variance_fn,
    screening_limits,
    unbin_hotspots,
)
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile, load_profile, profile_from_dict
from thintact_sdk.simulation import rotated as sim_rotated
from thintact_sdk.simulation.effects import resolve_physics
from thintact_sdk.simulation.noise import noise_variance_dn
from thintact_sdk.simulation.params import kernel_params
from thintact_sdk.simulation.simulator import Simulator


def _device(rows: int = 24, cols: int = 32, physics: dict | None = None) -> Profile:
    rng = np.random.default_rng(3)
    return profile_from_dict({
        "format": "thintact-profile/1", "name": "bin-test",
        "sensor": {"rows": rows, "cols": cols, "pixel_pitch_um": 10.0},
        "scene": {"rows": 12, "cols": 16, "pixel_pitch_um": 31.5},
        "mask": {"feature_um": 20.0, "phi": [int(v) for v in rng.choice([-1, 1], 31)]},
        "geometry": {"scene_to_mask_mm": 1.2, "mask_to_sensor_mm": 0.3},
        "noise": {"black_level_dn": 64, "read_noise_dn": 2, "electrons_per_dn": 4,
                  "saturation_dn": 4095},
        "physics": physics or {},
    })


def _block_mean(y: np.ndarray, b: int) -> np.ndarray:
    f, r, s, c = y.shape
    return y.reshape(f, r // b, b, s // b, b, c).mean(axis=(2, 4))


@pytest.mark.parametrize("physics", [
    {},
    {"pixel_angular_response": {"exponent": 3.0}},
    {"mask_misalignment": {"angle_deg": 0.0, "dx_um": 6.0, "dy_um": -4.0}},
    {"mask_leakage": {"transmittance": 0.03}},
], ids=["baseline", "angular", "shift", "leakage"])
def test_binned_device_is_the_block_mean(physics: dict) -> None:
    """A b×b block mean of the fine device's signal is the binned device's signal: the
    kernel integrates over pixel squares, so binning is exact (up to the radiometric
    expansion's own error)."""
    prof = _device(physics=physics)
    x = np.random.default_rng(0).random((2, 12, 16, 3))
    fine = Simulator(prof).forward_batch(x)
    for b in (2, 4):
        coarse = Simulator(binned_profile(prof, b)).forward_batch(x)
        want = _block_mean(fine, b)
        rel = np.sqrt(np.mean((coarse - want) ** 2) / np.mean(want**2))
        assert rel < 1e-4, (b, rel)


def test_binned_profile_refuses_a_factor_that_does_not_divide() -> None:
    with pytest.raises(ThinTactError, match="divide"):
        binned_profile(_device(24, 32), 5)


def test_auto_bin_factor() -> None:
    assert auto_bin_factor(128, 160) == 1
    assert auto_bin_factor(1024, 1280) == 8
    assert auto_bin_factor(256, 320) == 2
    with pytest.raises(ThinTactError, match="bin"):
        auto_bin_factor(1021, 1279)  # coprime: no common factor


def test_bin_frames_means_and_marks_saturated_blocks() -> None:
    m = np.arange(2 * 4 * 6 * 1, dtype=float).reshape(2, 4, 6, 1) + 100
    m[1, 0, 0, 0] = 4095.0
    out = bin_frames(m, 2, 4095.0)
    assert out.shape == (2, 2, 3, 1)
    assert out[0, 0, 0, 0] == pytest.approx(np.mean(m[0, :2, :2, 0]))
    assert out[1, 0, 0, 0] == 4095.0  # one saturated pixel: the whole block is out of χ²
    assert out[1, 0, 1, 0] == pytest.approx(np.mean(m[1, :2, 2:4, 0]))


def test_binned_variance_is_the_pixel_variance_over_b2() -> None:
    nz = _device().noise
    pred = np.linspace(64, 3000, 7)
    assert np.allclose(binned_variance_fn(4)(pred, nz), noise_variance_dn(pred, nz) / 16)


def test_unbin_hotspots_scales_rectangles() -> None:
    rep: dict[str, Any] = {"located": {"hotspots": [{"row0": 1, "row1": 3, "col0": 2, "col1": 5, "share": 0.5}]},
           "unexplained": {"hotspots": []}}
    unbin_hotspots(rep, 8)
    assert rep["located"]["hotspots"][0] == {"row0": 8, "row1": 24, "col0": 16, "col1": 40,
                                             "share": 0.5}


def test_family_candidates_oversized_at_paper_size_only() -> None:
    """At paper size refraction is not tried and the mask's angle is held at 0 (its
    rotated family is too large), but the mask shift is still screened."""
    paper = binned_profile(load_profile("thintact-paper"), 8)
    lim = screening_limits(paper)
    assert lim.dropped == ("refraction",)
    assert lim.held == {"mask_misalignment": ("angle_deg",), "refraction": ("n_scene_side",)}
    big = lim.not_screened
    assert set(big) == {"mask_misalignment.angle_deg", "refraction"}
    assert "MiB" in big["refraction"]
    assert big["mask_misalignment.angle_deg"].startswith("held at 0 (dx_um, dy_um screened)")
    assert screening_limits(_device(128, 160)).not_screened == {}
    assert screening_limits(_device(128, 160)) == ScreeningLimits()


def test_rotated_kernel_refuses_a_family_over_the_limit() -> None:
    """At the paper's size a 0.3° kernel's displacement family is ~8 GiB per axis (it used
    to run out of memory after minutes): refused before anything is allocated."""
    prof = load_profile("thintact-paper").with_physics(
        {"mask_misalignment": {"angle_deg": 0.3, "dx_um": 0.0, "dy_um": 0.0}})
    kp = kernel_params(prof, resolve_physics(prof.physics))
    assert sim_rotated.rotated_family_bytes(kp, 7) > sim_rotated.FAMILY_MAX_BYTES
    with pytest.raises(ThinTactError, match="rotated by 0.3"):
        sim_rotated.check_rotated_size(kp, 7)
    small = _device(128, 160, {"mask_misalignment": {"angle_deg": 0.3, "dx_um": 0.0, "dy_um": 0.0}})
    sim_rotated.check_rotated_size(kernel_params(small, resolve_physics(small.physics)), 7)


def test_rotated_kernel_refuses_too_many_terms_instead_of_crashing() -> None:
    """A 6° turn on a 128×160 unit passes the family check but needs 20 384 separable terms
    (8.7 GiB, measured) before compression; it crashed inside OpenBLAS (SIGSEGV) and is now
    refused with a ThinTactError naming the angle. The 1° kernel (874 terms) still builds."""
    prof = _device(128, 160, {"mask_misalignment": {"angle_deg": 6.0, "dx_um": 0.0, "dy_um": 0.0}})
    kp = kernel_params(prof, resolve_physics(prof.physics))
    with pytest.raises(ThinTactError, match="rotated by 6.*separable terms"):
        sim_rotated.check_rotated_terms(kp, 2, [1, 91], [1, 112])
    sim_rotated.check_rotated_terms(kp, 2, [1, 19], [1, 23])
    with pytest.raises(ThinTactError, match="rotated by 6"):
        Simulator(prof).linear_batch(np.ones((1, prof.scene.rows, prof.scene.cols, 3)))


def test_cli_bins_and_checks_the_fit_unbinned(tmp_path: Path) -> None:
    """``thintact diagnose --bin 2`` on a small device with a hidden angular response:
    the effect is found on the binned data, the report says how it was binned, the hotspots
    are in sensor pixels and the fit, evaluated unbinned, reaches the noise."""
    from thintact_sdk.apps.cli.main import main
    from thintact_sdk.formats.recording import RecordingWriter
    from thintact_sdk.simulation.noise import signal_to_dn

    prof = _device(32, 48)
    rng = np.random.default_rng(5)
    scenes = np.concatenate([np.ones((1, 12, 16, 3)), rng.random((3, 12, 16, 3))]).astype(np.float32)
    white = Simulator(prof).linear_batch(scenes[:1])[0]
    gains = [0.6 * 4031 / float(white[..., c].max()) for c in range(3)]
    hidden = Simulator(prof.with_physics({"pixel_angular_response": {"exponent": 4.0}}))
    signal = hidden.predict_signal_dn(scenes, gains)
    w = RecordingWriter(tmp_path / "rec", prof)
    for i, sc in enumerate(scenes):
        w.add(np.round(signal_to_dn(signal[i], prof.noise, rng)).astype(np.uint16), scene=sc)
    rc = main(["diagnose", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--quiet",
               "--bin", "2", "--max-effects", "1"])
    assert rc == 0
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert rep["binned"]["factor"] == 2 and rep["binned"]["rows"] == 16
    assert [f["effect"] for f in rep["findings"]][:1] == ["pixel_angular_response"]
    assert abs(rep["findings"][0]["params"]["exponent"] - 4.0) < 0.5
    assert rep["baseline"]["chi2_per_dof"] > 2.0
    assert rep["full_size"]["final"]["chi2_per_dof"] < 1.2
    fitted = json.loads((tmp_path / "o" / "fitted_profile.json").read_text())
    assert fitted["sensor"]["rows"] == 32  # the device itself, not the binned one


def _write_recording(prof: Profile, hidden: dict, path: Path, seed: int = 5) -> None:
    from thintact_sdk.formats.recording import RecordingWriter
    from thintact_sdk.simulation.noise import signal_to_dn

    rng = np.random.default_rng(seed)
    scenes = np.concatenate([np.ones((1, 12, 16, 3)), rng.random((3, 12, 16, 3))]).astype(np.float32)
    white = Simulator(prof).linear_batch(scenes[:1])[0]
    gains = [0.6 * 4031 / float(white[..., c].max()) for c in range(3)]
    signal = Simulator(prof.with_physics(hidden)).predict_signal_dn(scenes, gains)
    w = RecordingWriter(path, prof)
    for i, sc in enumerate(scenes):
        w.add(np.round(signal_to_dn(signal[i], prof.noise, rng)).astype(np.uint16), scene=sc)


def test_cli_screens_a_mask_shift_with_the_angle_held(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 17 at a small binned size: with the family limit lowered so that the rotated
    kernel and refraction count as too large (as at the paper's size), a hidden pure mask
    shift is still named with its parameters; the angle, held during the selection, is
    screened on coarser blocks afterwards and stays 0, and refraction is not tried."""
    from thintact_sdk.apps.cli.main import main
    from thintact_sdk.diagnosis.imaging import binning

    monkeypatch.setattr(binning, "DIAGNOSIS_FAMILY_BYTES", 1024.0)
    prof = _device(32, 48)
    _write_recording(prof, {"mask_misalignment": {"angle_deg": 0.0, "dx_um": 7.0, "dy_um": -4.0}},
                     tmp_path / "rec")
    rc = main(["diagnose", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--quiet",
               "--bin", "2", "--max-effects", "1"])
    assert rc == 0
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert set(rep["binned"]["not_screened"]) == {"refraction"}
    coarse = rep["binned"]["coarse_angle"]
    assert coarse["ran"] and not coarse["accepted"] and coarse["factor"] == 4
    f = rep["findings"][0]
    assert f["effect"] == "mask_misalignment"
    assert f["params"]["angle_deg"] == 0.0
    assert abs(f["params"]["dx_um"] - 7.0) < 1.0 and abs(f["params"]["dy_um"] + 4.0) < 1.0
    assert "Its angle was screened on the sensor binned 4×4" in f["evidence"]
    assert "2 parameter(s) must earn" in f["evidence"]  # BIC counts the fitted ones only
    assert rep["baseline"]["chi2_per_dof"] > 2.0
    assert rep["full_size"]["final"]["chi2_per_dof"] < 1.2


def test_unbinned_amplitude_admits_an_effect_binning_hides(tmp_path: Path) -> None:
    """A mask shift changes the binned prediction less than the unbinned one (binning
    averages its fine structure away). With the amplitude floor between the two, the
    binned diagnosis names it on its own only by its refit on each half of the frames (it
    is decisive and stable), and by its amplitude when the change is measured on the
    unbinned recording (as the CLI does)."""
    from thintact_sdk.diagnosis.imaging import DiagnoseOptions, diagnose, load_diagnosis_data
    from thintact_sdk.diagnosis.imaging.binning import bin_data, unbinned_amplitude_fn

    prof = _device(32, 48)
    shift = {"angle_deg": 0.0, "dx_um": 7.0, "dy_um": -4.0}
    _write_recording(prof, {"mask_misalignment": shift}, tmp_path / "rec")
    full = load_diagnosis_data(tmp_path / "rec")
    data = bin_data(full, 4)
    fine = unbinned_amplitude_fn(full)
    vec = np.array([0.0, 7.0, -4.0])
    fine_amp = fine({}, {"mask_misalignment": vec})
    coarse_amp = unbinned_amplitude_fn(data)({}, {"mask_misalignment": vec})
    assert fine_amp > 1.2 * coarse_amp > 0
    floor = float(np.sqrt(fine_amp * coarse_amp))
    opts = DiagnoseOptions(candidates=["mask_misalignment"], amp_floor=floor, max_effects=1,
                           held_params={"mask_misalignment": ("angle_deg",)})
    d = diagnose(data, variance_fn=binned_variance_fn(4), options=opts)
    f = d.report["findings"][0]
    assert f["effect"] == "mask_misalignment" and abs(f["params"]["dx_um"] - 7.0) < 1.0
    assert "unbinned" not in " ".join(d.selection.log)
    assert "stable under refit" in f["evidence"] and f["amplitude_fraction"] < floor
    assert all(abs(h["dx_um"] - 7.0) < 1.0 for h in f["refit_on_halves"])
    opts.fine_amplitude = fine
    d = diagnose(data, variance_fn=binned_variance_fn(4), options=opts)
    f = d.report["findings"][0]
    assert f["effect"] == "mask_misalignment" and abs(f["params"]["dx_um"] - 7.0) < 1.0
    assert "on the unbinned recording" in f["evidence"] and "refit_on_halves" not in f


def test_held_params_name_fit_parameters() -> None:
    """Held parameters are named by the effect's fit labels; a wrong label is refused."""
    from thintact_sdk.diagnosis.imaging.engine import held_indices

    assert held_indices({"mask_misalignment": ("angle_deg",)}) == {"mask_misalignment": (0,)}
    with pytest.raises(ThinTactError, match="not fit parameters of mask_misalignment"):
        held_indices({"mask_misalignment": ("angle",)})


@pytest.mark.parametrize(("case", "named"), [("refraction", True), ("geometry", False)])
def test_unscreened_refraction_is_named_beside_a_geometry_stand_in(concealed_case: Any, case: str,
                                                                    named: bool) -> None:
    """Where refraction cannot be screened (the paper's size: its kernel is out of reach,
    ``binned.not_screened``), a hidden n = 1.41 gap is fitted as a much shorter scene gap;
    that geometry finding then names refraction among its alternatives, with the index it
    implies, because the recording was never compared with it. A plain geometry error (4.95
    instead of 4.8 mm: n would be 1.008) is left alone. Shown on the concealed device with
    refraction held as the paper-size diagnosis holds it."""
    from thintact_sdk.diagnosis.imaging import DiagnoseOptions, diagnose, load_diagnosis_data

    data = load_diagnosis_data(concealed_case(case) / "recording")
    opts = DiagnoseOptions(candidates=["geometry", "refraction"], max_effects=1,
                           held_params={"refraction": ("n_scene_side",)})
    f = diagnose(data, options=opts).report["findings"][0]
    assert f["effect"] == "geometry"
    assert ("refraction" in f["alternatives"]) is named
    if named:
        z, d = f["params"]["scene_to_mask_mm"], f["params"]["mask_to_sensor_mm"]
        n = (data.profile.geometry.scene_to_mask_mm / data.profile.geometry.mask_to_sensor_mm) / (z / d)
        assert 1.3 < n < 1.5
        said = re.search(r"refraction \{'n_scene_side': ([0-9.]+)\} would look the same", f["evidence"])
        assert said is not None and float(said.group(1)) == pytest.approx(n, rel=1e-4)
        assert "was not screened on this device" in f["evidence"]
        assert "only a measured gap would" in f["evidence"]
    else:
        assert "not screened" not in f["evidence"]


def test_screened_refraction_is_never_named_as_an_unscreened_stand_in(concealed_case: Any) -> None:
    """With refraction screened (nothing held) the same recording names refraction itself,
    and no finding carries the unscreened stand-in sentence."""
    from thintact_sdk.diagnosis.imaging import DiagnoseOptions, diagnose, load_diagnosis_data

    data = load_diagnosis_data(concealed_case("refraction") / "recording")
    report = diagnose(data, options=DiagnoseOptions(candidates=["geometry", "refraction"], max_effects=1)).report
    assert report["findings"][0]["effect"] == "refraction"
    assert all("was not screened on this device" not in f["evidence"] for f in report["findings"])



def test_refraction_is_held_on_the_wide_device_where_a_fit_would_rebuild_it():
    """The wide device (128×160 at 40 um → 50×64 at 126 um, z 4.8, d 1 mm; air angles to 77°):
    refraction's one-axis family is far above the screening limit. The simulator can build it
    block by block for ``simulate``, but a fit rebuilds the kernel at every step, so the
    diagnosis drops it and names it beside a geometry finding it could stand behind."""
    from thintact_sdk.formats.profiles import profile_from_dict

    wide = profile_from_dict({  # the masks plugin's test device (mask_profiles.make_profile) made wide
        "format": "thintact-profile/1", "name": "mask-tiny",
        "sensor": {"rows": 128, "cols": 160, "pixel_pitch_um": 40.0},
        "scene": {"rows": 50, "cols": 64, "pixel_pitch_um": 126.0},
        "mask": {"feature_um": 60.0, "phi": [1 if i % 3 else -1 for i in range(127)]},
        "geometry": {"scene_to_mask_mm": 4.8, "mask_to_sensor_mm": 1.0},
        "noise": {"black_level_dn": 64.0, "read_noise_dn": 2.0, "electrons_per_dn": 4.0,
                  "saturation_dn": 4095.0},
    })
    kp = kernel_params(wide, resolve_physics({"refraction": {"n_scene_side": 1.41}}))
    from thintact_sdk.simulation import refracted as sim_refracted

    assert sim_refracted.refracted_family_bytes(kp) > 256 * 1024**2
    lim = screening_limits(wide)
    assert "refraction" in lim.dropped and "refraction" in lim.not_screened


def test_cli_names_unscreened_refraction_at_every_size(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 34: without binning too (a wide field of view), an effect out of reach is not
    screened, report.json says so (``not_screened``), and a geometry finding that shortens the
    scene gap enough to imply n ≥ 1.1 names refraction among its alternatives with that index."""
    from thintact_sdk.apps.cli.main import main
    from thintact_sdk.diagnosis.imaging import binning

    monkeypatch.setattr(binning, "DIAGNOSIS_FAMILY_BYTES", 1024.0)  # out of reach, as on a wide device
    prof = _device(32, 48)
    _write_recording(prof, {"geometry": {"scene_to_mask_mm": 1.2 / 1.41}}, tmp_path / "rec")
    rc = main(["diagnose", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--quiet",
               "--bin", "1", "--max-effects", "1"])
    assert rc == 0
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert "binned" not in rep and "refraction" in rep["not_screened"]
    f = rep["findings"][0]
    assert f["effect"] == "geometry" and "refraction" in f["alternatives"]
    said = re.search(r"refraction \{'n_scene_side': ([0-9.]+)\} would look the same", f["evidence"])
    assert said is not None and 1.3 < float(said.group(1)) < 1.5
