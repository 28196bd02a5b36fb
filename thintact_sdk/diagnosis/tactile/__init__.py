"""Diagnosis of the tactile simulation against real tactile frames (issue 13).

:func:`diagnose_tactile` compares real ball presses with the SDK's tactile simulation of the
same presses (press centre and depth fitted as nuisances), locates the mismatch, names the
missing effects from :data:`VOCABULARY`, fits them by BIC and reports
(:func:`write_tactile_outputs`); :func:`diagnose_tactile_pack` is what ``thintact
diagnose-tactile`` runs on a pack. :mod:`.correction` turns the fitted model into a LUT and a
physics correction for photometric stereo. :func:`fit_illumination_field` is the stand-alone
illumination-field term.
"""

from thintact_sdk.diagnosis.tactile.from_pack import diagnose_tactile_pack
from thintact_sdk.diagnosis.tactile.illumination import IlluminationFit, fit_illumination_field
from thintact_sdk.diagnosis.tactile.press_engine import (
    TactileDiagnosis,
    TactileDiagnosisOptions,
    diagnose_tactile,
)
from thintact_sdk.diagnosis.tactile.press_model import Press, TactileModel
from thintact_sdk.diagnosis.tactile.vocabulary import VOCABULARY

__all__ = ["VOCABULARY", "IlluminationFit", "Press", "TactileDiagnosis", "TactileDiagnosisOptions",
           "TactileModel", "diagnose_tactile", "diagnose_tactile_pack", "fit_illumination_field"]
