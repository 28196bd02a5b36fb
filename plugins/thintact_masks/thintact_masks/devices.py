"""Scaled-down copies of a device for fast mask optimisation runs."""

from __future__ import annotations

from thintact_masks.errors import MaskDesignError
from thintact_sdk.plugin_support import Profile


def scaled_profile(profile: Profile, scale: float) -> Profile:
    """A self-similar coarser device: same field of view, distances and mask extent.

    Sensor and scene pixel counts and the mask length K are multiplied by ``scale``
    (rounded, at least 2); pixel pitches and the mask feature size are divided by it, so the
    stripe slopes k_c, k_stripe, the field and the footprint-to-cell ratio are unchanged.
    φ is replaced by a placeholder of the new length (the mask is what is being designed).

    Parameters
    ----------
    profile
        The full-size device.
    scale
        Factor in (0, 1]; 1 returns the profile unchanged.
    """
    if not 0.0 < scale <= 1.0:
        raise MaskDesignError(f"--scale must be in (0, 1], got {scale}")
    if scale == 1.0:
        return profile

    def n(v: int) -> int:
        return max(2, int(round(v * scale)))

    k = n(profile.mask.K)
    upd = {
        "name": f"{profile.name}@{scale:g}",
        "sensor": profile.sensor.model_copy(update={
            "rows": n(profile.sensor.rows), "cols": n(profile.sensor.cols),
            "pixel_pitch_um": profile.sensor.pixel_pitch_um / scale}),
        "scene": profile.scene.model_copy(update={
            "rows": n(profile.scene.rows), "cols": n(profile.scene.cols),
            "pixel_pitch_um": profile.scene.pixel_pitch_um / scale}),
        "mask": profile.mask.model_copy(update={
            "feature_um": profile.mask.feature_um * profile.mask.K / k,
            "phi": [1 if i % 2 == 0 else -1 for i in range(k)], "phi_rows": None}),
    }
    out = profile.model_copy(update=upd, deep=True)
    out._source = profile.source
    return out
