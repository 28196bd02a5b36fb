"""Diagnosis of the tactile simulation against real tactile frames (issue 13, started).

Only the illumination-field term is here so far (:mod:`.illumination`).
"""

from thintact_sdk.tactile.sim_diagnosis.illumination import IlluminationFit, fit_illumination_field

__all__ = ["IlluminationFit", "fit_illumination_field"]
