"""Diagnosis: where and how a recording departs from the simulation (CONTRACTS §6).

``thintact diagnose RECORDING --out DIR`` simulates every frame that has a scene with the
profile's physics, fits the per-channel gains (nuisances), locates the residual (space,
channel, scene, signal level, radius, spatial frequency), names the missing effects of the
CONTRACTS §5 vocabulary (score tests on first-order signatures, full fits of the best,
greedy acceptance under a BIC criterion with a systematic-error allowance), flags local
structure no effect explains, and writes ``report.json``, ``report.html`` and
``fitted_profile.json``.

:func:`diagnose` on a recording directory is exactly what the command runs (same
``report.json`` content); the command only parses, prints and writes the outputs
(:mod:`~thintact_sdk.diagnosis.imaging.from_recording`).
"""

from __future__ import annotations

from thintact_sdk.diagnosis.imaging.engine import DiagnoseOptions, Diagnosis
from thintact_sdk.diagnosis.imaging.from_recording import (
    RecordingOptions,
    diagnose,
    diagnose_recording,
)
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData, load_diagnosis_data

__all__ = ["DiagnoseOptions", "Diagnosis", "DiagnosisData", "RecordingOptions", "diagnose",
           "diagnose_recording", "load_diagnosis_data"]
