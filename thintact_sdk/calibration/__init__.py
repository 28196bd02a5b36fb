"""Calibration of the T2S system matrices from slit scans (paper §D, Algorithms 1-3).

Modules: :mod:`lowrank` (per-slit compression), :mod:`slits` (slit stacks),
:mod:`solver` (Algorithms 1-3), :mod:`gauge` (the T2S gauge and comparisons),
:mod:`synthetic` (synthetic systems for tests), and the wizard / offline pipeline.
"""
