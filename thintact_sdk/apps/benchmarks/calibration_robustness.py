"""Calibration robustness: the paper's Alg. 1 vs the joint least-squares solve on simulated slit recordings.

See :mod:`thintact_sdk.calibration.stress_cases` for the cases (black-level offsets, exposure
jitter, missing dark frame, mask rotation, few averaged frames).
"""

from thintact_sdk.calibration.stress_cases import add_arguments, run

NAME = "calibration"
"""The benchmark's name: ``thintact bench calibration``."""

__all__ = ["add_arguments", "run"]
