"""Where real tactile frames depart from the model: space, colour, slope magnitude and
direction, inside/outside contact. All in units of χ² per value (1 = noise); the tactile axes
over the shared statistics of :mod:`~thintact_sdk.diagnosis.core.residual_axes`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from thintact_sdk.diagnosis.core.residual_axes import (
    binned_chi2,
    chi2_in,
    excess_map,
    find_hotspots,
    mean_z_map,
)
from thintact_sdk.diagnosis.core.residual_stats import normalised_residual
from thintact_sdk.diagnosis.tactile.press_model import Normals

SLOPE_EDGES = (0.0, 0.05, 0.2, 0.4, 0.7, 1.0, 1.5, np.inf)
"""Slope-magnitude bins (mm/mm) of the model surface."""


@dataclass
class TactileLocation:
    """Result of :func:`locate_residual`.

    Attributes
    ----------
    mean_z_map, excess_map
        ``H × W`` mean signed residual / σ and Σ(z² − 1) over frames and channels.
    report
        JSON-ready: hotspots, χ² by channel, region, slope magnitude and direction, summary.
    """

    mean_z_map: np.ndarray
    excess_map: np.ndarray
    report: dict[str, Any]


def locate_residual(images: np.ndarray, pred: np.ndarray, var: np.ndarray, valid: np.ndarray,
                    normals: list[Normals], contact_mm: float = 0.05) -> TactileLocation:
    """Break the residual down (see module docstring).

    Parameters
    ----------
    images, pred, var, valid
        ``P × H × W × 3`` measured, predicted, noise variance and used values.
    normals
        The model surface of each press (slopes, depth).
    contact_mm
        Depth above which a pixel counts as inside the contact.
    """
    z = normalised_residual(images, pred, var, valid)
    z2 = z * z
    ex = excess_map(z, valid)
    counts = valid.sum(axis=(0, 3)).astype(np.float64)
    mean_z = mean_z_map(z, valid)
    spots = find_hotspots(ex, counts)
    depth = np.stack([n.depth_mm for n in normals])
    slope = np.hypot(np.stack([n.gx for n in normals]), np.stack([n.gy for n in normals]))
    azim = np.degrees(np.arctan2(np.stack([n.gy for n in normals]),
                                 np.stack([n.gx for n in normals]))) % 360
    v3 = valid
    inside = (depth > contact_mm)[..., None] & v3
    rim = ((depth > 1e-4) & (depth <= contact_mm))[..., None] & v3
    outside = (depth <= 1e-4)[..., None] & v3
    by_region = {"inside_contact": chi2_in(z2, inside), "rim": chi2_in(z2, rim),
                 "outside": chi2_in(z2, outside)}
    share = {k: float((z2 - 1)[m].sum()) for k, m in
             (("inside_contact", inside), ("rim", rim), ("outside", outside))}
    tot = sum(max(v, 0.0) for v in share.values()) or 1.0
    slope_chi2, slope_n = binned_chi2(np.broadcast_to(slope[..., None], z2.shape)[v3], z2[v3],
                                      np.asarray(SLOPE_EDGES))
    by_slope: list[dict[str, Any]] = [
        {"lo": lo, "hi": None if np.isinf(hi) else hi, "chi2": float(c), "values": int(n)}
        for lo, hi, c, n in zip(SLOPE_EDGES[:-1], SLOPE_EDGES[1:], slope_chi2, slope_n, strict=True)]
    by_dir = []
    for k in range(8):
        m = ((slope > 0.1) & (azim >= 45 * k) & (azim < 45 * (k + 1)))[..., None] & v3
        by_dir.append({"azimuth_deg": 45 * k + 22.5, "chi2": chi2_in(z2, m),
                       "mean_z": [float(z[..., c][m[..., c]].mean()) if m[..., c].any() else 0.0
                                  for c in range(3)]})
    by_channel = [chi2_in(z2[..., c], v3[..., c]) for c in range(3)]
    worst_region = max(share, key=lambda k: share[k])
    hot = max(by_slope, key=lambda b: float(b["chi2"]) if np.isfinite(b["chi2"]) else -1.0)
    summary = (f"χ²/value by channel R {by_channel[0]:.2f}, G {by_channel[1]:.2f}, "
               f"B {by_channel[2]:.2f}; {100 * max(share[worst_region], 0) / tot:.0f} % of the "
               f"excess {worst_region.replace('_', ' ')} (χ² inside contact "
               f"{by_region['inside_contact']:.2f}, outside {by_region['outside']:.2f}); worst "
               f"slopes {hot['lo']}-{hot['hi'] or '∞'} (χ² {hot['chi2']:.2f}); "
               f"{len(spots)} spatial hotspot(s)")
    report = {"summary": summary, "hotspots": [h.to_json() for h in spots],
              "by_channel": by_channel, "by_region": by_region,
              "excess_share": {k: v / tot for k, v in share.items()},
              "by_slope_magnitude": by_slope, "by_slope_direction": by_dir}
    return TactileLocation(mean_z, ex, report)
