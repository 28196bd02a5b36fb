"""Reconstruction: T2S system matrices, calibration bundles, the joint filter, closed-form Tikhonov, metrics and direct generation."""
