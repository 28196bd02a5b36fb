"""Calibration robustness: the paper's Alg. 1 vs the joint least-squares solve on simulated slit recordings.

See :mod:`thintact_sdk.calibration.benchmark` for the cases (black-level offsets, exposure
jitter, missing dark frame, mask rotation, few averaged frames).
"""

from thintact_sdk.calibration.benchmark import add_arguments, run

__all__ = ["add_arguments", "run"]
