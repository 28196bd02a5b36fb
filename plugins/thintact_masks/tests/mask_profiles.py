"""The tiny device of the mask tests (a module of its own: several test folders have a conftest.py,
so importing "conftest" by name picks whichever was imported first)."""

from __future__ import annotations

from thintact_sdk.formats.profiles import Profile, profile_from_dict


def make_profile(rows: int = 24, cols: int = 30, n: int = 10, m: int = 12, K: int = 40,  # noqa: N803
                 pitch_um: float = 40.0, scene_pitch_um: float = 126.0,
                 feature_um: float = 60.0) -> Profile:
    """A small device with the paper's distances (z = 4.8 mm, d = 1 mm)."""
    return profile_from_dict({
        "format": "thintact-profile/1", "name": "mask-tiny",
        "sensor": {"rows": rows, "cols": cols, "pixel_pitch_um": pitch_um},
        "scene": {"rows": n, "cols": m, "pixel_pitch_um": scene_pitch_um},
        "mask": {"feature_um": feature_um, "phi": [1 if i % 3 else -1 for i in range(K)]},
        "geometry": {"scene_to_mask_mm": 4.8, "mask_to_sensor_mm": 1.0},
        "noise": {"black_level_dn": 64.0, "read_noise_dn": 2.0, "electrons_per_dn": 4.0,
                  "saturation_dn": 4095.0},
    })
