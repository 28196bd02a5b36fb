"""Tactile calibration: ball-press LUTs and gradient models, press packs, force gains, where they are stored, and their evaluation."""
