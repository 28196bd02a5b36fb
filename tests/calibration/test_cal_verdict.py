"""The verdict against the design's prediction: the margin comes from the profile, the failing
scene is named with its shortfall, and the fixed floors are an optional extra."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.calibration.prediction import Prediction
from thintact_sdk.calibration.validation import ValidationResult
from thintact_sdk.calibration.verdict import judge
from thintact_sdk.formats.profiles import CalibrationLimits


def _result(label: str, psnr_db: float, saturated: float = 0.0) -> ValidationResult:
    x = np.zeros((2, 2, 3), np.float32)
    return ValidationResult(label, psnr_db, 0.8, x, x, saturated)


PREDICTION = Prediction({"val_white": 30.0, "val_checker": 25.0}, [1.0, 1.0, 1.0], 1e4)


def test_a_scene_more_than_the_margin_below_its_prediction_fails_by_name() -> None:
    validation = [_result("val_white", 28.0), _result("val_checker", 24.9)]
    verdict = judge(validation, PREDICTION, None, CalibrationLimits())  # default margin 1.5 dB
    assert not verdict.passed and verdict.margin_db == 1.5
    assert [f.what for f in verdict.failures] == ["scene val_white"]
    assert "2.00 dB below the 30.00 dB predicted" in verdict.failures[0].detail
    shortfalls = {s["scene"]: s["shortfall_db"] for s in verdict.to_json()["scenes"]}
    assert shortfalls == {"val_white": pytest.approx(2.0), "val_checker": pytest.approx(0.1)}


def test_the_margin_is_the_profiles() -> None:
    validation = [_result("val_white", 28.0), _result("val_checker", 24.9)]
    assert judge(validation, PREDICTION, None, CalibrationLimits(psnr_margin_db=2.5)).passed
    strict = judge(validation, PREDICTION, None, CalibrationLimits(psnr_margin_db=0.05))
    assert [f.what for f in strict.failures] == ["scene val_white", "scene val_checker"]


def test_a_saturated_scene_is_blamed_on_saturation() -> None:
    verdict = judge([_result("val_white", 20.0, saturated=0.2)], PREDICTION, None, CalibrationLimits())
    assert "saturated" in verdict.failures[0].detail and "exposure" in verdict.failures[0].fix


def test_fixed_floors_are_an_optional_extra() -> None:
    validation = [_result("val_white", 29.5), _result("val_checker", 24.5)]  # within the margin
    assert judge(validation, PREDICTION, None, CalibrationLimits()).passed  # no floor by default
    floored = judge(validation, PREDICTION, None, CalibrationLimits(min_psnr_db=28.0, min_ssim=0.9))
    assert [f.what for f in floored.failures] == ["PSNR floor", "SSIM floor"]


def test_nothing_to_judge_fails() -> None:
    verdict = judge([], None, None, CalibrationLimits())
    assert not verdict.passed and verdict.failures[0].what == "no validation frames"
