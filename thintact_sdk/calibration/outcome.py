"""What a calibration produced: the bundle, the solver reports, validation, health and verdict
(:func:`thintact_sdk.calibration.pipeline.calibrate` returns it, the report renders it)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from thintact_sdk.calibration.collect import SlitCollection
from thintact_sdk.calibration.health import HealthReport
from thintact_sdk.calibration.prediction import Prediction
from thintact_sdk.calibration.registration import RegistrationResult
from thintact_sdk.calibration.selection import TauSelection
from thintact_sdk.calibration.solver import SolveReport
from thintact_sdk.calibration.validation import ValidationResult
from thintact_sdk.calibration.verdict import Verdict
from thintact_sdk.reconstruction.bundle import CalibrationBundle


@dataclass
class CalibrationOutcome:
    """What a calibration produced."""

    bundle: CalibrationBundle
    path: Path
    reports: list[SolveReport]
    collection: SlitCollection
    validation: list[ValidationResult]
    passed: bool
    registration: RegistrationResult | None = None
    reference: dict[str, Any] = field(default_factory=dict)
    tau_table: dict[str, float] = field(default_factory=dict)
    selection: TauSelection | None = None
    health: HealthReport | None = None
    prediction: Prediction | None = None
    verdict: Verdict | None = None
