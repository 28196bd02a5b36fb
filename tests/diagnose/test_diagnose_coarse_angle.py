"""A held mask angle fitted on coarser blocks (:mod:`thintact_sdk.diagnosis.imaging.coarse_angle`): on
the paper's device the 8×8-binned diagnosis cannot afford rotated kernels, so the angle is
searched on blocks where they are cheap; effects that stood in for the rotation are dropped."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.diagnose.test_diagnose_binning import _device, _write_recording
from thintact_sdk.diagnosis.imaging import DiagnoseOptions, diagnose, load_diagnosis_data
from thintact_sdk.diagnosis.imaging.binning import bin_data, binned_variance_fn
from thintact_sdk.diagnosis.imaging.coarse_angle import CoarseAngleInput, coarse_factor, next_angle
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData
from thintact_sdk.formats.profiles import load_profile

HELD = {"mask_misalignment": ("angle_deg",)}


def _recording(tmp_path: Path, angle: float, dx: float = 0.0, dy: float = 0.0) -> DiagnosisData:
    _write_recording(_device(32, 48), {"mask_misalignment": {"angle_deg": angle, "dx_um": dx, "dy_um": dy}},
                     tmp_path / "rec")
    return load_diagnosis_data(tmp_path / "rec")


def test_next_angle_is_the_parabola_vertex_or_a_step_downhill():
    def f(x: float) -> float:
        return 1000.0 * (x - 0.3) ** 2

    assert next_angle({a: f(a) for a in (0.0, 0.1, 0.2)}) == pytest.approx(0.3)
    # the vertex far outside the three angles: at most four spans beyond them
    assert next_angle({a: f(a) for a in (-0.06, -0.05, -0.04)}) == pytest.approx(-0.04 + 4 * 0.02)
    # not convex: a step of twice the span beyond the lowest
    assert next_angle({0.0: 5.0, 0.1: 4.0, 0.2: 1.0}) == pytest.approx(0.6)
    assert next_angle({0.0: 5.0, 1.4: 4.0, 1.45: 1.0}) == pytest.approx(1.5)  # kept within ±1.5°


def test_coarse_blocks_of_the_paper_device():
    """On the paper's device the 8×8 diagnosis fits the angle on 32×32 blocks: the 16×16-binned
    device's rotated build at 0.35° needs 0.68 GiB of families, the 32×32 one 0.31 GiB."""
    paper = load_profile("thintact-paper").with_physics({})
    assert coarse_factor(paper, 8) == 32
    assert coarse_factor(paper, 8, limit=1.0) == 0  # nothing small enough keeps 8 blocks a side


def test_a_held_rotation_is_fitted_on_coarse_blocks(tmp_path):
    """A 1° rotation with the angle held on the 2×2-binned data: the selection names a veil and
    a small mask shift in its place; the stage fits the angle on 4×4 blocks, drops the two
    stand-ins, and the diagnosis names the rotation alone, the fit reaching the noise."""
    full = _recording(tmp_path, 1.0)
    opts = DiagnoseOptions(max_effects=2, held_params=HELD, coarse_angle=CoarseAngleInput(full, 2))
    d = diagnose(bin_data(full, 2), variance_fn=binned_variance_fn(2), options=opts)
    assert [f["effect"] for f in d.report["findings"]] == ["mask_misalignment"]
    f = d.report["findings"][0]
    assert abs(f["params"]["angle_deg"] - 1.0) < 0.05
    assert f["params"]["dx_um"] == 0.0 and f["params"]["dy_um"] == 0.0
    assert "fitted on the sensor binned 4×4" in f["evidence"] and "held at the null value" not in f["evidence"]
    assert "1 parameter(s) must earn" in f["evidence"]  # the dropped shift is not counted
    stage = d.coarse_angle
    assert stage is not None and stage.accepted and stage.factor == 4
    rep = stage.to_json()
    assert set(rep["dropped"]) == {"veiling_glare", "the mask's shift"}
    assert rep["confirmed_dchi2"] > 1000 and len(rep["trials"]) >= 5
    assert d.report["final"]["chi2_per_dof"] < 1.1 < d.report["baseline"]["chi2_per_dof"]


def test_no_rotation_is_not_named_and_a_shift_stays(tmp_path):
    full = _recording(tmp_path, 0.0, 7.0, -4.0)
    opts = DiagnoseOptions(max_effects=1, held_params=HELD, coarse_angle=CoarseAngleInput(full, 2))
    d = diagnose(bin_data(full, 2), variance_fn=binned_variance_fn(2), options=opts)
    stage = d.coarse_angle
    assert stage is not None and stage.ran and not stage.accepted
    f = d.report["findings"][0]
    assert f["effect"] == "mask_misalignment" and f["params"]["angle_deg"] == 0.0
    assert abs(f["params"]["dx_um"] - 7.0) < 1.0
    assert "no rotation is named" in stage.summary()


def test_cli_fits_the_held_angle_on_coarser_blocks(tmp_path, monkeypatch, capsys):
    """As on the paper's device: with the family limit lowered the 2×2-binned diagnosis holds
    the angle, and the CLI fits it on coarser blocks; ``not_screened`` keeps only refraction,
    ``binned.coarse_angle`` says what was done, and the fitted profile has the angle."""
    from thintact_sdk.apps.cli.main import main
    from thintact_sdk.diagnosis.imaging import binning

    monkeypatch.setattr(binning, "DIAGNOSIS_FAMILY_BYTES", 1024.0)
    _recording(tmp_path, -0.8)
    rc = main(["diagnose", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--bin", "2",
               "--max-effects", "2"])
    assert rc == 0
    out = capsys.readouterr()
    assert "fitted on coarser blocks after the selection" in " ".join(out.err.split())
    assert "mask angle: The mask's angle, fitted on the sensor binned 4×4" in out.out
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert set(rep["binned"]["not_screened"]) == {"refraction"}
    coarse = rep["binned"]["coarse_angle"]
    assert coarse["accepted"] and coarse["factor"] == 4
    assert [f["effect"] for f in rep["findings"]] == ["mask_misalignment"]
    assert abs(rep["findings"][0]["params"]["angle_deg"] + 0.8) < 0.05
    assert rep["full_size"]["final"]["chi2_per_dof"] < 1.1
    fitted = json.loads((tmp_path / "o" / "fitted_profile.json").read_text())
    assert abs(np.asarray(fitted["physics"]["mask_misalignment"]["angle_deg"]) + 0.8) < 0.05


def test_window_amplitude_is_the_whole_sensors_change(tmp_path, monkeypatch):
    """The change a rotation makes, measured on windows of the unbinned sensor: with every
    window of the plan it is the whole sensor's change (the windows' kernels are the whole
    kernel on their pixels); with a spread subset of them, an estimate of it."""
    from thintact_sdk.diagnosis.imaging.coarse_angle import window_amplitude
    from thintact_sdk.simulation import rotated as sim_rotated
    from thintact_sdk.simulation import tiled as sim_tiled
    from thintact_sdk.simulation.effects import resolve_physics
    from thintact_sdk.simulation.params import kernel_params
    from thintact_sdk.simulation.simulator import Simulator, _expansion, clear_kernel_cache

    full = _recording(tmp_path, 0.0)
    after = {"mask_misalignment": {"angle_deg": 0.8, "dx_um": 0.0, "dy_um": 0.0}}
    gains = np.array([1.0, 0.9, 0.7])
    scenes = full.scenes[:4]
    clear_kernel_cache()
    y_b = Simulator(full.profile).kernel.apply(scenes) * gains
    y_a = Simulator(full.profile.with_physics(after)).kernel.apply(scenes) * gains
    whole = float(np.sqrt(np.sum((y_a - y_b) ** 2) / np.sum(y_b**2)))
    kp = kernel_params(full.profile.with_physics(after), resolve_physics(after))
    monkeypatch.setattr(sim_tiled, "WINDOW_FAMILY_BYTES",
                        sim_rotated.rotated_family_bytes(kp, _expansion(kp).rank) / 3)
    every, where = window_amplitude(full, {}, after, gains, bin_factor=4, n_windows=100)
    assert every == pytest.approx(whole, rel=1e-3) and "windows of the unbinned sensor" in where
    some, where = window_amplitude(full, {}, after, gains, bin_factor=4, n_windows=2)
    assert where.startswith("on 2 of") and 0.5 * whole < some < 2.0 * whole
    clear_kernel_cache()


def test_a_rotation_with_a_shift_gets_both(tmp_path):
    """A −0.8° turn with a 6/−4 um shift, the angle held on the 2×2 data: the angle is fitted
    on 4×4 blocks, then refitted there together with the shift, which is kept (it earns its
    two parameters' threshold) and named with the angle."""
    full = _recording(tmp_path, -0.8, 6.0, -4.0)
    opts = DiagnoseOptions(max_effects=2, held_params=HELD, coarse_angle=CoarseAngleInput(full, 2))
    d = diagnose(bin_data(full, 2), variance_fn=binned_variance_fn(2), options=opts)
    f = next(f for f in d.report["findings"] if f["effect"] == "mask_misalignment")
    assert abs(f["params"]["angle_deg"] + 0.8) < 0.05
    assert abs(f["params"]["dx_um"] - 6.0) < 1.0 and abs(f["params"]["dy_um"] + 4.0) < 1.0
    rep = d.coarse_angle.to_json() if d.coarse_angle else {}
    assert rep["shift"]["kept"] and rep["shift"]["dchi2"] > rep["shift"]["threshold"]
    assert "3 parameter(s) must earn" in f["evidence"]
    assert d.report["final"]["chi2_per_dof"] < 1.1
