"""Structured residuals that no effect explains: local defects (dust specks, dim or bright
columns and rows) found by aggregating the residual of every frame at each pixel.

For each sensor pixel the residuals of all frames and channels are combined into two
matched statistics, both standard normal when the residual is pure noise:

- multiplicative: t = Σ r·s/σ² / sqrt(Σ s²/σ²) (a pixel whose response is too low/high),
- additive: t = Σ r/σ² / sqrt(Σ 1/σ²) (a pixel with an offset),

with r the residual (DN), s the predicted signal above black (DN), σ² the noise variance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from thintact_sdk.diagnosis.core.residual_axes import Hotspot


@dataclass
class Structure:
    """Result of :func:`find_structure`.

    Attributes
    ----------
    significant
        True when a localized residual clears both the significance and the amplitude bar.
    hotspots
        Rectangles of the defects, with their share of the excess χ².
    mask
        ``R × S`` boolean, the defect pixels (dilated by a margin), to leave out of fits.
    t_mult
        ``R × S`` smoothed multiplicative statistic (noise units).
    rel_dev
        ``R × S`` smoothed relative response deviation (measured/predicted − 1).
    summary
        Plain words.
    """

    significant: bool
    hotspots: list[Hotspot]
    mask: np.ndarray
    t_mult: np.ndarray
    rel_dev: np.ndarray
    summary: str


def pixel_statistics(
    residual_dn: np.ndarray, signal_dn: np.ndarray, variance_dn2: np.ndarray, valid: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel ``(t_mult, t_add, rel_dev, info)``, each ``R × S``.

    ``rel_dev`` is the weighted least-squares relative gain error Σ r s/σ² / Σ s²/σ²;
    ``info`` = Σ s²/σ² its inverse variance.
    """
    w = np.where(valid, 1.0 / variance_dn2, 0.0)
    rs = np.sum(w * residual_dn * signal_dn, axis=(0, 3))
    ss = np.sum(w * signal_dn * signal_dn, axis=(0, 3))
    r1 = np.sum(w * residual_dn, axis=(0, 3))
    w1 = np.sum(w, axis=(0, 3))
    safe_ss = np.maximum(ss, 1e-12)
    t_mult = rs / np.sqrt(safe_ss)
    t_add = r1 / np.sqrt(np.maximum(w1, 1e-12))
    rel = rs / safe_ss
    return t_mult, t_add, rel, ss


def _smooth_t(t: np.ndarray, sigma_px: float) -> np.ndarray:
    norm = np.sqrt(1.0 / (4.0 * np.pi * sigma_px**2))
    return ndimage.gaussian_filter(t, sigma_px, mode="nearest") / norm


def find_structure(
    residual_dn: np.ndarray,
    signal_dn: np.ndarray,
    variance_dn2: np.ndarray,
    valid: np.ndarray,
    z: np.ndarray,
    sigma_thr: float = 7.0,
    rel_floor: float = 0.01,
    smooth_px: float = 1.5,
    max_area_frac: float = 0.05,
) -> Structure:
    """Find localized residual structure (see module docstring).

    Parameters
    ----------
    sigma_thr
        Significance bar for the smoothed pixel statistics and the column/row statistics.
    rel_floor
        Amplitude bar: a defect must change the response by at least this fraction
        (keeps honest sub-percent discretisation differences from counting).
    max_area_frac
        A region larger than this fraction of the sensor is not a local defect (a global
        misfit is the effects' business).
    """
    f, r, s, c = residual_dn.shape
    t_mult, t_add, rel, info = pixel_statistics(residual_dn, signal_dn, variance_dn2, valid)
    tm_s = _smooth_t(t_mult, smooth_px)
    ta_s = _smooth_t(t_add, smooth_px)
    w_rel = ndimage.gaussian_filter(info, smooth_px, mode="nearest")
    rel_s = ndimage.gaussian_filter(rel * info, smooth_px, mode="nearest") / np.maximum(w_rel, 1e-12)
    spot = ((np.abs(tm_s) > sigma_thr) & (np.abs(rel_s) > rel_floor)) | (np.abs(ta_s) > 2 * sigma_thr)
    # compact spots first (elongated components are lines: the line statistics judge them)
    lab0, n0 = ndimage.label(spot)
    compact = np.zeros((r, s), bool)
    for k, sl in enumerate(ndimage.find_objects(lab0)[:n0]):
        if sl is None:
            continue
        h, w = sl[0].stop - sl[0].start, sl[1].stop - sl[1].start
        if max(h, w) <= 6 * min(h, w):
            compact[sl] |= lab0[sl] == k + 1
    keep = ~ndimage.binary_dilation(compact, iterations=3)
    # columns and rows: a line defect is weak per pixel but strong along its length
    tm_k = np.where(keep, t_mult, 0.0)
    ri_k = np.where(keep, rel * info, 0.0)
    in_k = np.where(keep, info, 0.0)
    col_t = tm_k.sum(axis=0) / np.sqrt(np.maximum(keep.sum(axis=0), 1))
    col_rel = ri_k.sum(axis=0) / np.maximum(in_k.sum(axis=0), 1e-12)
    row_t = tm_k.sum(axis=1) / np.sqrt(np.maximum(keep.sum(axis=1), 1))
    row_rel = ri_k.sum(axis=1) / np.maximum(in_k.sum(axis=1), 1e-12)
    bad_cols = np.flatnonzero((np.abs(col_t) > sigma_thr) & (np.abs(col_rel) > rel_floor))
    bad_rows = np.flatnonzero((np.abs(row_t) > sigma_thr) & (np.abs(row_rel) > rel_floor))
    exc = np.sum(np.where(valid, z * z - 1.0, 0.0), axis=(0, 3))
    total = float(np.sum(np.maximum(exc, 0.0))) or 1.0
    spot = compact
    lab, n = ndimage.label(spot)
    spots: list[Hotspot] = []
    mask = np.zeros((r, s), bool)
    words: list[str] = []
    for k, sl in enumerate(ndimage.find_objects(lab)[:n]):
        if sl is None:
            continue
        comp = lab[sl] == k + 1
        r0, r1, c0, c1 = sl[0].start, sl[0].stop, sl[1].start, sl[1].stop
        if (r1 - r0) * (c1 - c0) > max_area_frac * r * s or comp.sum() < 2:
            continue
        share = float(np.sum(np.maximum(exc[r0:r1, c0:c1], 0.0))) / total
        spots.append(Hotspot(int(r0), int(r1), int(c0), int(c1), share))
        mask[max(0, r0 - 2) : r1 + 2, max(0, c0 - 2) : c1 + 2] = True
        dev = float(rel_s[sl][comp][np.argmax(np.abs(rel_s[sl][comp]))])
        kind = "dark" if dev < 0 else "bright"
        words.append(
            f"a {kind} spot at rows {r0}-{r1}, columns {c0}-{c1} "
            f"(response {dev:+.0%}, {float(np.max(np.abs(tm_s[sl][comp]))):.0f}σ)"
        )
    for lines, t_line, rel_line, is_col in ((bad_cols, col_t, col_rel, True), (bad_rows, row_t, row_rel, False)):
        for grp in np.split(lines, np.flatnonzero(np.diff(lines) > 1) + 1) if lines.size else []:
            a, b = int(grp[0]), int(grp[-1]) + 1
            if (b - a) > 0.1 * (s if is_col else r):
                continue
            if is_col:
                h = Hotspot(0, r, a, b, float(np.sum(np.maximum(exc[:, a:b], 0.0))) / total)
                mask[:, max(0, a - 1) : b + 1] = True
            else:
                h = Hotspot(a, b, 0, s, float(np.sum(np.maximum(exc[a:b, :], 0.0))) / total)
                mask[max(0, a - 1) : b + 1, :] = True
            spots.append(h)
            dev = float(rel_line[a:b].mean())
            what = "column" if is_col else "row"
            rng_txt = f"{a}" if b - a == 1 else f"{a}-{b - 1}"
            words.append(
                f"a {'dim' if dev < 0 else 'bright'} {what} {rng_txt} (response {dev:+.1%}, "
                f"{float(np.max(np.abs(t_line[a:b]))):.0f}σ along its length)"
            )
    spots.sort(key=lambda h: -h.share)
    if spots:
        summary = (
            "A localized residual remains that no effect of the vocabulary explains: "
            + "; ".join(words)
            + ". It looks like a sensor defect (dust, a dead or dim line) or something on the "
            "mask; it is left out of the effect fits."
        )
    else:
        summary = (
            "No localized structure remains: every pixel's residual, aggregated over frames "
            f"and channels, stays within {sigma_thr:.0f}σ or below a {rel_floor:.0%} response change."
        )
    return Structure(bool(spots), spots, mask, tm_s, rel_s, summary)
