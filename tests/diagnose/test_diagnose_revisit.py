"""Revisiting earlier rounds (:func:`thintact_sdk.diagnosis.imaging.select._revisit_rounds`):
a greedy choice that a later effect shows to be wrong is swapped for its round's rival."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.diagnose.test_diagnose_binning import _device, _write_recording
from thintact_sdk.diagnosis.imaging import DiagnoseOptions, diagnose, load_diagnosis_data, select


def test_a_round_won_by_the_wrong_effect_is_swapped_once_the_later_one_is_in(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Leakage and a 6 um sensor blur hidden. Round 1 is made to prefer a veiling glare (its
    Δχ² raised above the others', as an independent renderer's recording had it); once the
    blur is in, mask leakage in the glare's place fits better, so it is swapped: the finding
    is the leakage, at its true value, with the glare as its alternative."""
    _write_recording(_device(32, 48), {"mask_leakage": {"transmittance": 0.03},
                                       "sensor_blur": {"sigma_um": 6.0}}, tmp_path / "rec")
    orig = select._round_candidates
    rounds: list[list[str]] = []

    def glare_first(state: Any, *a: Any, **k: Any) -> Any:
        fitted, scores = orig(state, *a, **k)
        rounds.append([r.name for r in fitted])
        if len(rounds) == 1:
            glare = next(r for r in fitted if r.name == "veiling_glare")
            glare.dchi2 = max(r.dchi2 or 0.0 for r in fitted) + 500.0
        return fitted, scores

    monkeypatch.setattr(select, "_round_candidates", glare_first)
    d = diagnose(load_diagnosis_data(tmp_path / "rec"), options=DiagnoseOptions(
        max_effects=2, candidates=["veiling_glare", "mask_leakage", "sensor_blur"]))
    found = {f["effect"]: f for f in d.report["findings"]}
    assert set(found) == {"mask_leakage", "sensor_blur"}
    leak = found["mask_leakage"]
    assert abs(leak["params"]["transmittance"] - 0.03) < 0.003
    assert leak["swapped_from"] == "veiling_glare" and leak["alternatives"] == ["veiling_glare"]
    assert "first accepted veiling_glare" in leak["evidence"]
    assert abs(found["sensor_blur"]["params"]["sigma_um"] - 6.0) < 1.0
    assert set(d.fitted_profile.physics) == {"mask_leakage", "sensor_blur"}
