"""The unbinned stage of a binned diagnosis (:mod:`thintact_sdk.diagnosis.imaging.unbinned`): effects
finer than a block are refitted, or named, on the unbinned frames; a right model is left
alone; an excess under the amplitude floor is named when it is stable under refit, and
reported, not named, when it is not."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.diagnose.test_diagnose_binning import _device, _write_recording
from thintact_sdk.diagnosis.imaging import DiagnoseOptions, diagnose, load_diagnosis_data
from thintact_sdk.diagnosis.imaging.binning import (
    bin_data,
    binned_variance_fn,
    unbinned_amplitude_fn,
)
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData
from thintact_sdk.diagnosis.imaging.unbinned import (
    EXCESS_Z,
    UnbinnedInput,
    excess_z,
    unbinned_candidates,
)

BIN = 4


def _recording(tmp_path: Path, hidden: dict) -> tuple[DiagnosisData, DiagnosisData]:
    _write_recording(_device(32, 48), hidden, tmp_path / "rec")
    full = load_diagnosis_data(tmp_path / "rec")
    return full, bin_data(full, BIN)


def test_excess_z_counts_standard_deviations_of_chi2():
    assert excess_z(1.0, 10**6) == 0.0
    assert excess_z(1.001, 2 * 10**6) == pytest.approx(1.0)
    assert excess_z(0.99, 200) == pytest.approx(-0.1)


def test_stage_candidates_act_after_the_kernel_and_are_not_closed_form():
    names = ["pixel_angular_response", "mask_misalignment", "sensor_blur", "scene_blur", "veiling_glare",
             "stray_light", "sensor_gamma"]
    assert unbinned_candidates(names, {}) == ["sensor_blur", "scene_blur", "veiling_glare", "sensor_gamma"]
    assert unbinned_candidates(names, {"sensor_blur": np.array([3.0])}) == ["scene_blur", "veiling_glare",
                                                                            "sensor_gamma"]


def test_a_blur_binning_misjudges_is_refitted_at_full_size(tmp_path):
    """8 um of sensor blur on 10 um pixels: on 4×4-binned data it is named but fitted at
    about half its width (binning only approximates it); left so, the unbinned frames are 38σ
    off and a veiling glare was named there to absorb it. The stage refits it on unbinned
    frames instead: the right width, and nothing else named."""
    full, data = _recording(tmp_path, {"sensor_blur": {"sigma_um": 8.0}})
    opts = DiagnoseOptions(max_effects=2)
    binned_only = diagnose(data, variance_fn=binned_variance_fn(BIN), options=opts)
    sigma_binned = binned_only.report["findings"][0]["params"]["sigma_um"]
    assert abs(sigma_binned - 8.0) > 2.0
    opts.unbinned = UnbinnedInput(full, BIN)
    d = diagnose(data, variance_fn=binned_variance_fn(BIN), options=opts)
    assert [f["effect"] for f in d.report["findings"]] == ["sensor_blur"]
    f = d.report["findings"][0]
    assert abs(f["params"]["sigma_um"] - 8.0) < 0.5
    assert "refitted on 4 unbinned frames" in f["evidence"]
    assert "(0.80 pixels)" in f["evidence"]  # the device's 10 um pixels, not the 40 um blocks
    assert d.unbinned is not None and d.unbinned.ran and d.unbinned.excess_z > EXCESS_Z
    rep = d.unbinned.to_json()
    assert rep["refitted"] == ["sensor_blur"] and rep["accepted"] == []
    assert "Refitted there: sensor_blur" in str(rep["summary"])


def test_an_effect_the_binned_stage_did_not_name_is_named_on_unbinned_frames(tmp_path):
    """The binned selection given no time (it names nothing, as when binning hides an effect
    entirely: the paper device's blurs); the stage, with its own budget, names the blur on
    unbinned frames and says why there."""
    full, data = _recording(tmp_path, {"sensor_blur": {"sigma_um": 8.0}})
    opts = DiagnoseOptions(max_effects=2, time_budget_s=0.0, unbinned=UnbinnedInput(full, BIN))
    d = diagnose(data, variance_fn=binned_variance_fn(BIN), options=opts)
    assert [f["effect"] for f in d.report["findings"]] == ["sensor_blur"]
    f = d.report["findings"][0]
    assert abs(f["params"]["sigma_um"] - 8.0) < 0.5
    assert "Named on 4 unbinned frames" in f["evidence"]
    assert d.unbinned is not None and d.unbinned.to_json()["accepted"] == ["sensor_blur"]


def test_an_excess_under_the_amplitude_floor_is_named_when_stable(tmp_path):
    """An 8 um blur with the floor set above its change of the prediction: decisive and
    stable under refit (the same width on each half of the frames), so it is named all the
    same, its amplitude stated, and refitted on the unbinned frames to its true width."""
    full, data = _recording(tmp_path, {"sensor_blur": {"sigma_um": 8.0}})
    fine_amp = unbinned_amplitude_fn(full)({}, {"sensor_blur": np.array([8.0])})
    opts = DiagnoseOptions(max_effects=2, amp_floor=1.5 * fine_amp, unbinned=UnbinnedInput(full, BIN))
    d = diagnose(data, variance_fn=binned_variance_fn(BIN), options=opts)
    assert [f["effect"] for f in d.report["findings"]] == ["sensor_blur"]
    f = d.report["findings"][0]
    assert abs(f["params"]["sigma_um"] - 8.0) < 0.5
    assert "stable under refit" in f["evidence"] and f["amplitude_fraction"] < 1.5 * fine_amp
    halves = [h["sigma_um"] for h in f["refit_on_halves"]]
    assert len(halves) == 2 and abs(halves[0] - halves[1]) < 0.25 * max(halves)
    assert "below_floor" not in d.report


def test_an_earlier_choice_the_later_effect_makes_unnecessary_is_dropped(tmp_path):
    """Binned 4×4, an 8 um sensor blur is first taken for mask leakage (round 1); once the
    blur is in (round 2), the leakage's joint refit goes to 0 and the revisit of round 1
    drops it: one finding, which says so."""
    _full, data = _recording(tmp_path, {"sensor_blur": {"sigma_um": 8.0}})
    d = diagnose(data, variance_fn=binned_variance_fn(BIN), options=DiagnoseOptions(max_effects=2))
    assert [f["effect"] for f in d.report["findings"]] == ["sensor_blur"]
    f = d.report["findings"][0]
    assert f["absorbed"] == ["mask_leakage"] and "makes mask_leakage" in f["evidence"]
    assert any(line.startswith("revisited mask_leakage") for line in d.selection.log)
    assert set(d.fitted_profile.physics) == {"sensor_blur"}


def test_a_right_model_is_left_alone(tmp_path):
    """A hidden angular response is named on the binned data; its fit is exact there (a
    kernel-stage effect commutes with binning), so the unbinned frames agree with the noise
    and the stage neither refits nor names anything."""
    full, data = _recording(tmp_path, {"pixel_angular_response": {"exponent": 4.0}})
    opts = DiagnoseOptions(max_effects=2, unbinned=UnbinnedInput(full, BIN))
    d = diagnose(data, variance_fn=binned_variance_fn(BIN), options=opts)
    assert [f["effect"] for f in d.report["findings"]] == ["pixel_angular_response"]
    assert d.unbinned is not None and not d.unbinned.ran
    assert abs(d.unbinned.excess_z) < EXCESS_Z
    assert d.unbinned.check["chi2_per_dof"] < 1.05
    assert "also fits the unbinned frames" in d.unbinned.summary()


def test_cli_reports_the_stage(tmp_path):
    from thintact_sdk.apps.cli.main import main

    _write_recording(_device(32, 48), {"sensor_blur": {"sigma_um": 8.0}}, tmp_path / "rec")
    rc = main(["diagnose", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--quiet", "--bin", str(BIN),
               "--max-effects", "2"])
    assert rc == 0
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    stage = rep["binned"]["unbinned_stage"]
    assert stage["ran"] and stage["refitted"] == ["sensor_blur"]
    assert stage["before"]["chi2_per_dof"] > rep["full_size"]["final"]["chi2_per_dof"]
    assert rep["full_size"]["before_unbinned_stage"] == stage["before"]
    assert abs(rep["findings"][0]["params"]["sigma_um"] - 8.0) < 0.5
    fitted = json.loads((tmp_path / "o" / "fitted_profile.json").read_text())
    assert abs(fitted["physics"]["sensor_blur"]["sigma_um"] - 8.0) < 0.5


def _write_half_hidden(prof, hidden: dict, path, seed: int = 5) -> None:
    """A recording whose odd frames have ``hidden`` and whose even frames do not."""
    from thintact_sdk.formats.recording import RecordingWriter
    from thintact_sdk.simulation.noise import signal_to_dn
    from thintact_sdk.simulation.simulator import Simulator

    rng = np.random.default_rng(seed)
    scenes = np.concatenate([np.ones((1, 12, 16, 3)), rng.random((5, 12, 16, 3))]).astype(np.float32)
    white = Simulator(prof).linear_batch(scenes[:1])[0]
    gains = [0.6 * 4031 / float(white[..., c].max()) for c in range(3)]
    plain = Simulator(prof).predict_signal_dn(scenes, gains)
    with_it = Simulator(prof.with_physics(hidden)).predict_signal_dn(scenes, gains)
    w = RecordingWriter(path, prof)
    for i, sc in enumerate(scenes):
        sig = with_it[i] if i % 2 else plain[i]
        w.add(np.round(signal_to_dn(sig, prof.noise, rng)).astype(np.uint16), scene=sc)


def test_a_small_device_names_a_stable_effect_under_the_floor(tmp_path):
    """Not only binned: a leakage the data show (Δχ² far over the BIC threshold) with the
    floor set above its change of the prediction is still named, because its refit on each
    half of the frames clears the criterion at the same value; its amplitude is stated."""
    _write_recording(_device(32, 48), {"mask_leakage": {"transmittance": 0.03}}, tmp_path / "rec")
    data = load_diagnosis_data(tmp_path / "rec")
    named = diagnose(data, options=DiagnoseOptions(max_effects=1, candidates=["mask_leakage"]))
    assert [f["effect"] for f in named.report["findings"]] == ["mask_leakage"]
    assert "below_floor" not in named.report and "refit_on_halves" not in named.report["findings"][0]
    change = named.selection.rounds[0].amplitude_dn
    sig = float(np.sqrt(np.mean((named.final_pred_dn - 64.0) ** 2)))
    d = diagnose(data, options=DiagnoseOptions(max_effects=1, candidates=["mask_leakage"],
                                               amp_floor=2.0 * change / sig))
    f = d.report["findings"][0]
    assert f["effect"] == "mask_leakage" and abs(f["params"]["transmittance"] - 0.03) < 0.005
    assert f["amplitude_fraction"] < 2.0 * change / sig and "stable under refit" in f["evidence"]
    assert all(abs(h["transmittance"] - 0.03) < 0.005 for h in f["refit_on_halves"])
    assert "below_floor" not in d.report


def test_an_unstable_effect_under_the_floor_is_reported_not_named(tmp_path):
    """A leakage in every other frame only: decisive on all frames, but its refit on the
    even frames finds none and on the odd ones the whole of it, so it is not stable under
    refit. Under the floor it is not named but listed in ``below_floor`` with its fitted
    value and both refits; with no floor it is named (the amplitude rule alone)."""
    _write_half_hidden(_device(32, 48), {"mask_leakage": {"transmittance": 0.03}}, tmp_path / "rec")
    data = load_diagnosis_data(tmp_path / "rec")
    opts = DiagnoseOptions(max_effects=1, candidates=["mask_leakage"])
    named = diagnose(data, options=opts)
    assert [f["effect"] for f in named.report["findings"]] == ["mask_leakage"]
    change = named.selection.rounds[0].amplitude_dn
    sig = float(np.sqrt(np.mean((named.final_pred_dn - 64.0) ** 2)))
    opts.amp_floor = 2.0 * change / sig
    d = diagnose(data, options=opts)
    assert d.report["findings"] == []
    low = d.report["below_floor"]
    assert [b["effect"] for b in low] == ["mask_leakage"] and low[0]["data"] == "fit data"
    halves = sorted(h["transmittance"] for h in low[0]["refit_on_halves"])
    assert halves[0] < 0.01 and abs(halves[1] - 0.03) < 0.006


def test_a_rival_as_good_on_unbinned_frames_is_an_alternative(tmp_path, monkeypatch):
    """The full-size alternative rule: a rival whose fit in place of an accepted effect comes
    within the selection's tolerance (2·ln n + 0.2 %) is an alternative, one outside it is
    not. (The rivals' fits are stubbed to land just inside and outside; on the paper's
    device a 10 um sensor blur and a 50.6 um scene blur are such a pair for real,
    ``tools/diagnose_paper_size.py --case sensor_blur``.)"""
    from thintact_sdk.diagnosis.imaging import select
    from thintact_sdk.diagnosis.imaging.deadline import Deadline
    from thintact_sdk.diagnosis.imaging.forward_model import DiagnosisModel, default_simulate
    from thintact_sdk.diagnosis.imaging.select import CandidateResult
    from thintact_sdk.diagnosis.imaging.stats import default_variance_fn
    from thintact_sdk.diagnosis.imaging.unbinned import full_size_alternatives

    full, _ = _recording(tmp_path, {"sensor_blur": {"sigma_um": 8.0}})
    model = DiagnosisModel(full, default_simulate, default_variance_fn(), sys_frac=1e-3)
    values = {"sensor_blur": np.array([8.0])}
    seen: list[str] = []

    def fake_score(model, values, ev0, cand):
        seen.append(cand.name)
        return CandidateResult(cand.name, cand.k, 1e9, cand.null(model.profile))

    def fake_fit(model, without, ev0, res, deadline, **kw):
        own = ev0.chi2 - model.evaluate(values).chi2
        res.fitted = np.array([32.0]) if res.name == "scene_blur" else np.array([0.01])
        res.dchi2 = own * (0.999 if res.name == "scene_blur" else 0.9)
        return res

    monkeypatch.setattr(select, "score_candidate", fake_score)
    monkeypatch.setattr(select, "fit_candidate", fake_fit)
    alts = full_size_alternatives(model, values, ["sensor_blur"], ["scene_blur", "veiling_glare", "sensor_blur"],
                                  Deadline.after(60))
    assert seen == ["scene_blur", "veiling_glare"]  # never itself
    assert [a.name for a in alts["sensor_blur"]] == ["scene_blur"]
    assert alts["sensor_blur"][0].own_dchi2 > 1000 and alts["sensor_blur"][0].vector[0] == 32.0


def test_full_size_alternatives_reach_the_finding(tmp_path, monkeypatch):
    from thintact_sdk.diagnosis.imaging import unbinned
    from thintact_sdk.diagnosis.imaging.unbinned import FullSizeAlternative

    full, data = _recording(tmp_path, {"sensor_blur": {"sigma_um": 8.0}})
    monkeypatch.setattr(unbinned, "full_size_alternatives", lambda *a, **k: {
        "sensor_blur": [FullSizeAlternative("scene_blur", 6200.0, 6277.0, np.array([32.0]))]})
    opts = DiagnoseOptions(max_effects=2, unbinned=UnbinnedInput(full, BIN))
    d = diagnose(data, variance_fn=binned_variance_fn(BIN), options=opts)
    f = d.report["findings"][0]
    assert f["effect"] == "sensor_blur" and f["alternatives"] == ["scene_blur"]
    assert "On 4 unbinned frames scene_blur {'sigma_um': 32.0} explains the recording about as well" in f["evidence"]
    assert "To tell sensor_blur from scene_blur" in f["evidence"]
    assert d.unbinned is not None and d.unbinned.to_json()["alternatives"] == {"sensor_blur": ["scene_blur"]}


def test_a_rival_better_on_unbinned_frames_takes_the_place(tmp_path, monkeypatch):
    """A rival that beats the binned choice on unbinned frames by more than the tolerance
    replaces it (the paper device's 10 um sensor blur, which the binned data took for a
    50.6 um scene blur): the finding, the fitted profile and the evidence say so."""
    from thintact_sdk.diagnosis.imaging import unbinned
    from thintact_sdk.diagnosis.imaging.unbinned import FullSizeAlternative

    full, data = _recording(tmp_path, {"sensor_blur": {"sigma_um": 8.0}})
    monkeypatch.setattr(unbinned, "full_size_alternatives", lambda *a, **k: {
        "sensor_blur": [FullSizeAlternative("scene_blur", 7000.0, 6277.0, np.array([32.0]), 50.0, 9.0)]})
    opts = DiagnoseOptions(max_effects=2, unbinned=UnbinnedInput(full, BIN))
    d = diagnose(data, variance_fn=binned_variance_fn(BIN), options=opts)
    f = d.report["findings"][0]
    assert f["effect"] == "scene_blur" and f["params"] == {"sigma_um": 32.0}
    assert "in place of sensor_blur, which the binned data preferred" in f["evidence"]
    assert "lowers χ² by 7000 against 6277" in f["evidence"]
    assert set(d.fitted_profile.physics) == {"scene_blur"}
    assert d.unbinned is not None and d.unbinned.to_json()["replaced"] == {"sensor_blur": "scene_blur"}
    assert "scene_blur explains the recording better than sensor_blur" in d.unbinned.summary()
