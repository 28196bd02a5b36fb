"""Lensless imaging: forward simulation, T2S system matrices, reconstruction, metrics."""
