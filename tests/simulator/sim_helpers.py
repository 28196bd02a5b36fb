"""Tiny test devices for the simulator tests."""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.formats.profiles import Profile, profile_from_dict


def tiny_profile(physics: dict[str, Any] | None = None, *, rows: int = 6, cols: int = 8,
                 pitch_um: float = 100.0, scene_rows: int = 4, scene_cols: int = 5,
                 scene_pitch_um: float = 300.0, feature_um: float = 80.0, k: int = 16,
                 z_mm: float = 2.0, d_mm: float = 0.5, seed: int = 1) -> Profile:
    """A few-pixel device with large angles (so the radiometric factor matters)."""
    rng = np.random.default_rng(seed)
    phi = [int(v) for v in rng.choice([-1, 1], k)]
    phi_rows = [int(v) for v in rng.choice([-1, 1], k)]
    return profile_from_dict({
        "format": "thintact-profile/1", "name": "tiny",
        "sensor": {"rows": rows, "cols": cols, "pixel_pitch_um": pitch_um},
        "scene": {"rows": scene_rows, "cols": scene_cols, "pixel_pitch_um": scene_pitch_um},
        "mask": {"feature_um": feature_um, "phi": phi, "phi_rows": phi_rows},
        "geometry": {"scene_to_mask_mm": z_mm, "mask_to_sensor_mm": d_mm},
        "noise": {"black_level_dn": 64.0, "read_noise_dn": 2.0, "electrons_per_dn": 4.0,
                  "saturation_dn": 4095.0},
        "physics": physics or {},
    })


def rel_rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS of ``a - b`` relative to the RMS of ``b``."""
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2)))
