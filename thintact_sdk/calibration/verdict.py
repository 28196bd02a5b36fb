"""Pass or fail, and why: the unit against its own design's prediction, its health, and floors.

A calibration fails when

* a validation scene reconstructs more than ``calibration_limits.psnr_margin_db`` (default
  1.5 dB) below the PSNR predicted for this design (:mod:`thintact_sdk.calibration.prediction`);
* the health check located a defect (:mod:`thintact_sdk.calibration.health`);
* the registration check failed (wizard);
* the profile sets the optional fixed floors ``min_psnr_db`` / ``min_ssim`` and the means are
  below them;
* there is no validation frame to judge by.

Each failure names what failed, by how much, why, and a fix to try.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_sdk.calibration.health import HealthReport
from thintact_sdk.calibration.prediction import Prediction
from thintact_sdk.calibration.registration import RegistrationResult
from thintact_sdk.calibration.validation import ValidationResult
from thintact_sdk.formats.profiles import CalibrationLimits

_DEFECT_FIX = {
    "dust speck": "clean the mask and the sensor cover glass at that spot, then calibrate again",
    "column defect": "a sensor column misbehaves: check the sensor (dead/noisy column) or mask it out",
    "row defect": "a sensor row misbehaves: check the sensor (dead/noisy row) or mask it out",
    "dim column": "a sensor column responds weakly: check for a shadow or a sensor column defect",
    "bright column": "a sensor column responds too strongly: check for a hot column or stray light",
    "dim row": "a sensor row responds weakly: check for a shadow or a sensor row defect",
    "bright row": "a sensor row responds too strongly: check for a hot row or stray light",
    "shading blemish": "a soft shadow (dust on the sensor's cover glass or on the mask): clean them at "
                       "that spot, then calibrate again",
    "ghost": "a reflection doubles the image: check the mask-to-cover-glass gap for a reflective "
             "surface (add an anti-reflection coating or an absorbing spacer), then calibrate again",
}


@dataclass
class Failure:
    """One reason for FAIL."""

    what: str
    detail: str
    fix: str

    def to_json(self) -> dict[str, str]:
        return dict(self.__dict__)


@dataclass
class SceneCheck:
    """A validation scene against its prediction."""

    label: str
    measured_db: float
    predicted_db: float

    @property
    def shortfall_db(self) -> float:
        return self.predicted_db - self.measured_db


@dataclass
class Verdict:
    """The outcome: ``passed``, the failures, and the per-scene comparison."""

    passed: bool
    failures: list[Failure] = field(default_factory=list)
    scenes: list[SceneCheck] = field(default_factory=list)
    margin_db: float = 1.5

    def to_json(self) -> dict[str, Any]:
        return {
            "passed": self.passed, "margin_db": self.margin_db,
            "failures": [f.to_json() for f in self.failures],
            "scenes": [{"scene": s.label, "measured_db": round(s.measured_db, 2),
                        "predicted_db": round(s.predicted_db, 2),
                        "shortfall_db": round(s.shortfall_db, 2)} for s in self.scenes],
        }


def judge(validation: list[ValidationResult], prediction: Prediction | None, health: HealthReport | None,
          limits: CalibrationLimits, registration: RegistrationResult | None = None) -> Verdict:
    """Pass/fail with every reason (see the module docstring)."""
    out = Verdict(True, margin_db=limits.psnr_margin_db)
    if not validation:
        out.failures.append(Failure("no validation frames", "the recording has no scene that is "
                                    "neither dark nor a slit, so nothing can be judged",
                                    "record validation scenes (the wizard does) and calibrate again"))
    if prediction is not None:
        for v in validation:
            pred = prediction.psnr_db.get(v.label)
            if pred is None:
                continue
            check = SceneCheck(v.label, v.psnr_db, pred)
            out.scenes.append(check)
            if check.shortfall_db > limits.psnr_margin_db:
                why = ("its measurement saturated" if v.saturated_fraction > 1e-3 else
                       "see the health section: defects, noise above the profile's, slit residuals")
                out.failures.append(Failure(
                    f"scene {v.label}",
                    f"{v.psnr_db:.2f} dB is {check.shortfall_db:.2f} dB below the {pred:.2f} dB "
                    f"predicted for this design (allowed {limits.psnr_margin_db:g} dB); {why}",
                    "lower the exposure or the display brightness" if v.saturated_fraction > 1e-3 else
                    "fix what the health section names; with no defect named, average more frames "
                    "per pattern (--frames) and check the profile's geometry and mask"))
    if health is not None:
        for d in health.defects:
            out.failures.append(Failure(d.kind, d.describe(), _DEFECT_FIX.get(d.kind, "inspect the unit there")))
    if registration is not None and not registration.passed:
        out.failures.append(Failure("registration", "; ".join(registration.problems) or "failed",
                                    "correct display.origin_px as the registration section says"))
    if validation:
        mean_psnr = float(np.mean([v.psnr_db for v in validation]))
        mean_ssim = float(np.mean([v.ssim for v in validation]))
        if limits.min_psnr_db is not None and mean_psnr < limits.min_psnr_db:
            out.failures.append(Failure("PSNR floor", f"mean PSNR {mean_psnr:.2f} dB is below the "
                                        f"profile's floor of {limits.min_psnr_db:g} dB",
                                        "check the health section, or lower calibration_limits.min_psnr_db "
                                        "if the design cannot reach it (see the predicted PSNR)"))
        if limits.min_ssim is not None and mean_ssim < limits.min_ssim:
            out.failures.append(Failure("SSIM floor", f"mean SSIM {mean_ssim:.3f} is below the "
                                        f"profile's floor of {limits.min_ssim:g}",
                                        "check the health section, or lower calibration_limits.min_ssim"))
    out.passed = not out.failures
    return out
