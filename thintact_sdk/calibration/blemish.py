"""Shading blemishes: soft shadows on the sensor found from the flat and validation frames.

Dust on the sensor's cover glass (or on the mask, close to the sensor) casts a soft shadow:
every frame is multiplied by ``g = 1 − depth·exp(−r²/2σ²)`` around the speck, a few to a
few tens of percent deep and a few pixels wide. The slit residuals hardly show it: the
two-term model ``Po X Qoᵀ + Pc X Qcᵀ`` absorbs most of a soft multiplicative shadow into its
row and column profiles (a 12 %-deep shadow of σ 4 px left a mean slit χ² of 1.002). What it
cannot absorb stays in the ratio of every known frame to its prediction:

1. **ratio map**: ``m = measured / predicted`` per sensor pixel, the inverse-variance
   weighted mean over the flat and validation frames and the channels (weights
   ``predicted² / V(predicted)``, ``V`` the noise measured on the slit residuals, saturated
   pixels left out), with its propagated standard deviation;
2. **separable part removed**: what the model absorbed comes back as a row and a column
   band through the shadow (the ratio ~1.5 % high along them for the 12 % shadow). The
   map's row medians and column medians are subtracted, which takes those bands (and any
   dim column or row, a separable defect found elsewhere) out while a compact shadow, a
   small part of every row and column, stays: ``D = m − row median − column median``;
3. **matched filter at every scale**: at each pixel and each σ of :data:`SCALES_PX` the
   least-squares depth of a shadow ``depth·G_σ`` centred there, ``a = −Σ G·D / Σ G²``, and
   its standard deviation: the propagated noise of ``D`` through the filter, scaled up by
   the ratio of ``D``'s robust spread to its propagated noise where the frames scatter more
   than their noise (model error), and never below the filtered map's own robust spread
   (correlated model error that a per-pixel figure misses);
4. **threshold from the frames at hand**: a shadow is reported where ``a`` exceeds
   :func:`detection_z` standard deviations: a false-alarm probability of
   :data:`FALSE_ALARM` over the map's independent resolution elements at every scale
   (Bonferroni), so the threshold follows the sensor's size and the frames' noise, not a
   constant tuned to one unit. Located at the filtered map's peak (refined by a parabola),
   with the σ and depth of the best scale. A peak on the border row or column is not
   reported (its centre lies on or beyond the edge), nor one shallower than the threshold
   times the single pixels' robust scatter of ``D`` (the model's texture on this unit), nor
   one on the row or column band of a shadow at least twice as deep (the echo of what the
   model absorbed of that one).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.stats import norm

SCALES_PX: tuple[float, ...] = (1.5, 2.0, 2.8, 4.0, 5.6, 8.0, 11.0)
"""Shadow widths σ searched (sensor pixels): √2 steps over the 2-8 px of soft dust and one
step beyond each end, so a shadow at either end of the range peaks inside the search."""
FALSE_ALARM = 1e-3
"""Probability that a healthy unit's noise alone produces a reported blemish anywhere on
the sensor at any scale (the threshold of :func:`detection_z`)."""


@dataclass(frozen=True)
class Blemish:
    """A soft shadow on the sensor.

    Attributes
    ----------
    row, col
        Its centre (sensor pixels, sub-pixel).
    sigma_px
        Its Gaussian σ (sensor pixels; the best of :data:`SCALES_PX`, refined).
    depth
        Fraction of the light it takes at its centre (0.12: 12 % darker).
    z
        Its depth in standard deviations of the depth estimate.
    threshold_z
        The detection threshold it cleared.
    fit_z
        Its depth in standard deviations of the frames' propagated noise alone (the figure
        its location and width were chosen by).
    """

    row: float
    col: float
    sigma_px: float
    depth: float
    z: float
    threshold_z: float
    fit_z: float = 0.0

    def bounds(self, shape: tuple[int, int]) -> tuple[int, int, int, int]:
        """``(row0, row1, col0, col1)``: its half-maximum box (radius 1.18 σ), clipped to ``shape``."""
        h = max(1.0, 1.1774 * self.sigma_px)
        r0, r1 = int(np.floor(self.row - h)), int(np.ceil(self.row + h)) + 1
        c0, c1 = int(np.floor(self.col - h)), int(np.ceil(self.col + h)) + 1
        return max(r0, 0), min(r1, shape[0]), max(c0, 0), min(c1, shape[1])


@dataclass
class RatioMap:
    """The weighted ratio measured/predicted (``R × S``) and its propagated standard deviation."""

    ratio: np.ndarray
    sigma: np.ndarray
    frames: int


def ratio_map(frames: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]],
              variance: Callable[[np.ndarray], np.ndarray], shape: tuple[int, int]) -> RatioMap:
    """Step 1 of the module docstring.

    Parameters
    ----------
    frames
        Per flat or validation frame ``(residual, predicted, usable)``: ``R × S × C``
        measured − predicted and predicted (DN above dark), and the unsaturated pixels.
    variance
        ``V(predicted) -> DN²``: the measured noise model (``NoiseEstimate.variance``).
    shape
        ``(R, S)``.
    """
    num = np.zeros(shape)
    wsum = np.zeros(shape)
    n = 0
    for res, pred, ok in frames:
        p = np.asarray(pred, np.float64)
        v = np.asarray(variance(p), np.float64)
        use = ok & (p > 0) & (v > 0)
        w = np.where(use, p * p / np.where(use, v, 1.0), 0.0)
        num += np.sum(w * np.where(use, res / np.where(use, p, 1.0), 0.0), axis=2)
        wsum += np.sum(w, axis=2)
        n += 1
    seen = wsum > 0
    ratio = np.where(seen, 1.0 + num / np.where(seen, wsum, 1.0), 1.0)
    sigma = np.where(seen, 1.0 / np.sqrt(np.where(seen, wsum, 1.0)), np.inf)
    return RatioMap(ratio, sigma, n)


def _robust_sd(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    if x.size == 0:
        return 0.0
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def detection_z(shape: tuple[int, int], scales: tuple[float, ...] = SCALES_PX,
                false_alarm: float = FALSE_ALARM) -> float:
    """Standard deviations a shadow's depth must reach: the one-sided Gaussian quantile of
    ``false_alarm`` divided among the map's independent resolution elements (area / 4πσ²
    at each scale, at least one)."""
    area = float(shape[0] * shape[1])
    elements = sum(max(area / (4.0 * np.pi * s * s), 1.0) for s in scales)
    return float(norm.isf(false_alarm / elements))


def _gauss1(sigma: float) -> np.ndarray:
    """Peak-1 Gaussian of ``sigma`` pixels sampled over ±3σ."""
    h = int(np.ceil(3.0 * sigma))
    x = np.arange(-h, h + 1, dtype=float)
    return np.asarray(np.exp(-0.5 * (x / sigma) ** 2))


def _gauss(sigma: float) -> np.ndarray:
    g1 = _gauss1(sigma)
    return np.asarray(np.outer(g1, g1))


def _separable(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``x`` correlated with ``outer(w, w)`` (mirrored edges)."""
    return np.asarray(ndimage.correlate1d(ndimage.correlate1d(x, w, axis=0, mode="reflect"), w, axis=1, mode="reflect"))


def find_blemishes(rm: RatioMap, scales: tuple[float, ...] = SCALES_PX,
                   false_alarm: float = FALSE_ALARM) -> list[Blemish]:
    """Steps 2-4 of the module docstring on a ratio map; the blemishes, deepest first."""
    shape = rm.ratio.shape
    seen = np.isfinite(rm.sigma)
    if not seen.any():
        return []
    base = np.where(seen, rm.ratio, np.nan)
    d = base - np.nanmedian(base, axis=1, keepdims=True)
    d = d - np.nanmedian(d, axis=0, keepdims=True)
    d = np.where(np.isfinite(d), d, 0.0)
    var = np.where(seen, rm.sigma**2, 0.0)
    inflate = max(1.0, _robust_sd(d[seen]) / max(float(np.median(rm.sigma[seen])), 1e-12))
    thr = detection_z(shape, scales, false_alarm)
    pixel_sd = _robust_sd(d[seen])
    depth_maps, z_maps, fit_maps = [], [], []
    for s in scales:
        g1 = _gauss1(s)  # the shadow is separable: two 1-D passes (a paper-size map in seconds)
        g2 = float(np.sum(g1 * g1)) ** 2
        a = -_separable(d, g1) / g2
        sd_prop = np.sqrt(_separable(var, g1 * g1)) / g2
        # correlated model error: the filtered map's own spread, outside what stands out
        z0 = a / np.maximum(inflate * sd_prop, 1e-12)
        quiet = np.abs(z0) < 3.0
        sd_emp = _robust_sd(a[quiet]) if quiet.sum() > 0.5 * a.size else _robust_sd(a)
        sd = np.maximum(inflate * sd_prop, sd_emp)
        depth_maps.append(a)
        z_maps.append(np.where(seen, a / np.maximum(sd, 1e-12), 0.0))
        fit_maps.append(np.where(seen, a / np.maximum(sd_prop, 1e-12), 0.0))
    zs, fits = np.stack(z_maps), np.stack(fit_maps)  # scales × R × S
    best = zs.max(axis=0)
    peaks = (best == ndimage.maximum_filter(best, size=3, mode="nearest")) & (best > thr)
    peaks[[0, -1], :] = False  # a peak on the border row or column: its centre lies on or
    peaks[:, [0, -1]] = False  # beyond the edge, where it cannot be located
    found: list[Blemish] = []
    for r, c in sorted(zip(*np.nonzero(peaks), strict=True), key=lambda rc: -best[rc]):
        # where and how wide: the least-squares fit (the propagated noise's z); whether: the
        # significance against the larger of propagated and empirical spreads
        k = int(np.argmax(fits[:, r, c]))
        if zs[k, r, c] <= thr:
            continue
        s = scales[k]
        if any((r - b.row) ** 2 + (c - b.col) ** 2 < (1.5 * max(s, b.sigma_px)) ** 2 for b in found):
            continue  # the same shadow seen at a neighbouring peak
        row = r + _vertex(fits[k], r, c, axis=0)
        col = c + _vertex(fits[k], r, c, axis=1)
        sigma = _scale_vertex(fits[:, r, c], scales, k)
        depth = _depth_at(d, r, c, sigma)
        if depth <= thr * pixel_sd:
            continue  # shallower than single pixels scatter: model texture, not a shadow
        if any(depth < 0.5 * b.depth and (abs(row - b.row) < 1.5 * b.sigma_px or abs(col - b.col) < 1.5 * b.sigma_px)
               for b in found):
            continue  # an echo: the model spreads what it absorbed of a deeper shadow along its row and column
        found.append(Blemish(float(row), float(col), sigma, depth, float(zs[k, r, c]), thr, float(fits[k, r, c])))
    return found


def _depth_at(d: np.ndarray, r: int, c: int, sigma: float) -> float:
    """Least-squares depth of a shadow ``depth·G_σ`` centred on pixel ``(r, c)`` of ``d``."""
    g = _gauss(sigma)
    h = g.shape[0] // 2
    pad = np.pad(d, h, mode="reflect")
    win = pad[r : r + 2 * h + 1, c : c + 2 * h + 1]
    return float(-np.sum(g * win) / np.sum(g * g))


def _vertex(z: np.ndarray, r: int, c: int, axis: int) -> float:
    """Sub-pixel offset of the peak of ``z`` at ``(r, c)`` along ``axis`` (parabola, ±0.5)."""
    n = z.shape[axis]
    i = r if axis == 0 else c
    if i == 0 or i == n - 1:
        return 0.0
    lo = z[r - 1, c] if axis == 0 else z[r, c - 1]
    hi = z[r + 1, c] if axis == 0 else z[r, c + 1]
    curv = lo + hi - 2.0 * z[r, c]
    return 0.0 if curv >= 0 else float(np.clip(0.5 * (lo - hi) / curv, -0.5, 0.5))


def _scale_vertex(z: np.ndarray, scales: tuple[float, ...], k: int) -> float:
    """The best σ: the parabola vertex of ``z`` over log σ around ``scales[k]``."""
    if k == 0 or k == len(scales) - 1:
        return float(scales[k])
    ls = np.log(scales[k - 1 : k + 2])
    coef = np.polyfit(ls, z[k - 1 : k + 2], 2)
    if coef[0] >= 0:
        return float(scales[k])
    return float(np.exp(np.clip(-coef[1] / (2 * coef[0]), ls[0], ls[2])))
