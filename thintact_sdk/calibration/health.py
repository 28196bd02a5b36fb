"""The unit's health: slit-fit residuals against the noise, measured noise, located defects.

After the solve every slit frame is taken from the recording again (its kept, read-only
frame: :class:`~thintact_sdk.formats.recording.Recording` reads each file once) and compared
with the calibrated model ``Po X Qoᵀ + Pc X Qcᵀ`` of its own scene. The residual ``r`` of a
healthy unit is noise:

* **noise measured**: ``E[r²] = a + b·signal`` fitted over signal-level bins (read noise
  ``√(a − 1/12)``, ``1/b`` electrons per DN, divided by the frames averaged) and compared with
  the profile's noise section;
* **χ² map**: ``r²/σ²`` per sensor pixel averaged over the slit frames and channels, with
  ``σ²`` the measured noise model; structure in it is something the separable model cannot
  describe. Hotspots (Gaussian-smoothed map far above its robust spread) are located and
  classified: a compact spot is a **dust speck** (on the mask or the sensor cover), a
  one-pixel-wide line a **column/row defect**;
* **dim or bright columns and rows**: a gain on one sensor column is separable, so the solve
  absorbs it into ``Qo``/``Qc`` instead of leaving a residual; it is found as a dip or peak of
  the open response ``Qo·1`` (``Po·1`` for rows) against its smooth neighbourhood;
* **ghost**: a faint displaced copy of the whole image (a reflection between mask and cover
  glass), found by a least-squares fit to the slit frames at every 2-D offset (not
  separable) or as an echo of the design's coding pattern in the calibrated matrices
  (separable), see :mod:`thintact_sdk.calibration.ghost`; located by its offset and strength.

Every defect names its kind, where it is (sensor rows/columns) and how strong it is.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage

from thintact_sdk.calibration.blemish import find_blemishes, ratio_map
from thintact_sdk.calibration.classify import classify_scene, is_dark, is_slit
from thintact_sdk.calibration.collect import SlitCollection, exposure_scale, signal_of
from thintact_sdk.calibration.ghost import GhostScan, find_ghosts
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import NoiseSpec
from thintact_sdk.formats.recording import Recording
from thintact_sdk.host.blas import blas_threads
from thintact_sdk.reconstruction.filter_training import scene_for_channels
from thintact_sdk.reconstruction.t2s import SystemMatrices
from thintact_sdk.simulation.noise import QUANTISATION_VARIANCE_DN2

_MEDIAN_CHI2_1 = 0.45494
"""Median of a χ² variable with one degree of freedom (r²/σ² of Gaussian noise)."""
NOISE_FIT_CAP = 20_000_000
"""Slit-frame entries (pixels × channels) up to which the noise fit uses every one; above it, a
random subsample of about this many (spread evenly over the slit frames): the bin quantiles and
medians of millions of entries are those of all of them within their own sampling error, and
memory stays bounded (a paper-size unit has 912 × 1024 × 1280 × 3 = 3.6e9)."""
NOISE_FIT_SEED = 0
"""Seed of that subsample: the same recording always gives the same noise fit."""
HOTSPOT_SIGMA_PX = 1.5
"""Smoothing of the χ² map before hotspots are looked for (sensor pixels)."""
HOTSPOT_ROBUST_SIGMAS = 10.0
"""A hotspot stands this many robust standard deviations above the map's median…"""
HOTSPOT_MIN_EXCESS = 0.5
"""…and at least this far above it in χ² (50 % more residual power than the noise)."""
LINE_ROBUST_SIGMAS = 8.0
LINE_MIN_DEVIATION = 0.02
"""A column or row whose open response departs from its neighbours' by more than both
``LINE_ROBUST_SIGMAS`` robust standard deviations and 2 % is a dim/bright line."""


@dataclass
class NoiseEstimate:
    """Noise measured on the slit residuals against the profile's.

    Attributes
    ----------
    read_noise_dn, electrons_per_dn
        Measured per captured frame (the averaging over ``frames_averaged`` undone).
    profile_read_noise_dn, profile_electrons_per_dn
        The profile's values.
    variance_offset_dn2, variance_slope
        ``E[r²] = offset + slope·signal`` of the averaged frames (DN², DN).
    """

    read_noise_dn: float
    electrons_per_dn: float
    profile_read_noise_dn: float
    profile_electrons_per_dn: float
    variance_offset_dn2: float
    variance_slope: float

    def variance(self, signal_dn: np.ndarray) -> np.ndarray:
        """Measured noise variance (DN²) of the recording's frames at ``signal_dn`` above black."""
        return self.variance_offset_dn2 + self.variance_slope * np.clip(signal_dn, 0.0, None)

    def to_json(self) -> dict[str, float]:
        return {k: round(float(v), 4) for k, v in self.__dict__.items()}


@dataclass
class Defect:
    """Something wrong with the unit, located on the sensor.

    Attributes
    ----------
    kind
        ``dust speck``, ``dim column``, ``bright column``, ``dim row``, ``bright row``,
        ``column defect``, ``row defect``, ``ghost``, ``shading blemish``.
    row0, row1, col0, col1
        Sensor pixel bounds (inclusive-exclusive) of the affected area.
    centre
        ``(row, col)`` of its centre (sensor pixels).
    strength
        χ² excess over the noise (hotspots), relative gain change (lines, e.g. −0.15), the
        ghost's brightness relative to the image (e.g. 0.08) or a shading blemish's depth
        (fraction of the light it takes at its centre, e.g. 0.12).
    channels
        Channel names where it shows.
    offset_px
        A ghost's displacement ``(rows, cols)`` from the image, sensor pixels.
    note
        How it shows (ghosts: separable or not), with the offset in um.
    """

    kind: str
    row0: int
    row1: int
    col0: int
    col1: int
    centre: tuple[float, float]
    strength: float
    channels: list[str] = field(default_factory=list)
    offset_px: tuple[int, int] | None = None
    note: str = ""

    def describe(self) -> str:
        """One line a person can act on."""
        if self.kind == "ghost" and self.offset_px is not None:
            dy, dx = self.offset_px
            return (f"ghost: a copy of the sensor image displaced by {dy:+d} rows, {dx:+d} columns "
                    f"{self.note} at {100 * self.strength:.1f} % of its brightness")
        where = (f"sensor rows {self.row0}-{self.row1 - 1}, columns {self.col0}-{self.col1 - 1} "
                 f"(centre row {self.centre[0]:.0f}, column {self.centre[1]:.0f})")
        if self.kind == "shading blemish":
            return f"shading blemish at {where}: {100 * self.strength:.1f} % darker at its centre {self.note}"
        if self.kind.endswith(("column", "row")) and not self.kind.endswith("defect"):
            line = f"column {self.col0}" if self.kind.endswith("column") else f"row {self.row0}"
            return (f"{self.kind} at sensor {line}: {100 * self.strength:+.1f} % response "
                    f"({', '.join(self.channels)})")
        return f"{self.kind} at {where}: residual {self.strength:.1f}× the noise power above normal"

    def to_json(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["centre"] = [round(float(v), 1) for v in self.centre]
        d["strength"] = round(float(self.strength), 4)
        if self.offset_px is not None:
            d["offset_px"] = [int(v) for v in self.offset_px]
        d["description"] = self.describe()
        return d


@dataclass
class HealthReport:
    """Per-slit χ², χ² map, measured noise and defects of one calibration."""

    slit_chi2: dict[str, float]
    chi2_map: np.ndarray
    noise: NoiseEstimate
    defects: list[Defect]
    column_deviation: np.ndarray
    row_deviation: np.ndarray
    ghost_scans: list[GhostScan] = field(default_factory=list)

    @property
    def mean_chi2(self) -> float:
        """Mean ``r²/σ²`` over all slit frames (1 for pure noise)."""
        return float(np.mean(list(self.slit_chi2.values()))) if self.slit_chi2 else float("nan")

    def to_json(self) -> dict[str, Any]:
        return {
            "mean_slit_chi2": round(self.mean_chi2, 4),
            "worst_slits": dict(sorted(((k, round(v, 3)) for k, v in self.slit_chi2.items()),
                                       key=lambda kv: -kv[1])[:5]),
            "noise": self.noise.to_json(),
            "defects": [d.to_json() for d in self.defects],
            "ghost_scans": [_scan_json(g) for g in self.ghost_scans],
        }


def _scan_json(g: GhostScan) -> dict[str, Any]:
    """One ghost scan for ``health.json``; a scan that did not run (no lags: its name says
    why) has ``"scanned": false`` and null offset and strength, not a strength of 0."""
    if not g.lags:
        return {"scan": g.name, "scanned": False, "lag_px": None, "strength": None, "significant": False}
    strength = g.estimate if np.isfinite(g.estimate) else g.value
    return {"scan": g.name, "scanned": True, "lag_px": g.lag, "strength": round(strength, 4),
            "significant": g.significant}


_BIN_BLOCK = 1 << 20
"""Entries binned at a time by :func:`_fit_noise`."""


def _fit_noise(pred: np.ndarray, r2: np.ndarray, noise: NoiseSpec, frames: int,
               dark_frames: int) -> NoiseEstimate:
    """``E[r²] = a + b·signal`` over 24 signal-quantile bins (robust: each bin's median of
    ``r²`` / 0.4549, the median of a χ²₁ variable, so a local defect does not bias it).
    ``r2`` is reordered (its median is taken in place).

    ``dark_frames`` captures were averaged into the subtracted dark level: their read noise is
    in every residual too, and is taken out of the per-frame read noise reported.
    """
    edges = np.unique(np.quantile(pred, np.linspace(0.0, 1.0, 25)))
    # the bin of each entry as one byte (24 bins), found a block at a time: no index array of
    # the entries' size in int64 beside them (160 MB at the noise-fit cap)
    idx = np.empty(pred.shape, np.uint8)
    top = max(len(edges) - 2, 0)
    for start in range(0, pred.size, _BIN_BLOCK):
        block = slice(start, start + _BIN_BLOCK)
        found = np.searchsorted(edges, pred[block], side="right")
        found -= 1
        idx[block] = np.clip(found, 0, top)
    xs, ys = [], []
    for bin_index in range(len(edges) - 1):
        sel = idx == bin_index
        if np.count_nonzero(sel) > 10:
            xs.append(float(np.mean(pred[sel], dtype=np.float64)))
            ys.append(float(np.median(r2[sel])) / _MEDIAN_CHI2_1)
    del idx
    # the last use of r2: its median taken in place (the caller's entries are spent)
    offset: float = float(np.median(r2, overwrite_input=True)) / _MEDIAN_CHI2_1
    slope: float = 0.0
    if len(xs) >= 2 and np.ptp(xs) > 0:
        slope, offset = (float(v) for v in np.polyfit(xs, ys, 1))
    a, b = max(float(offset), QUANTISATION_VARIANCE_DN2 / frames), max(float(slope), 1e-12)
    dark_share = 1.0 + (1.0 / dark_frames if dark_frames > 0 else 0.0)
    read = float(np.sqrt(max(a * frames / dark_share - QUANTISATION_VARIANCE_DN2, 0.0)))
    return NoiseEstimate(read, 1.0 / (b * frames), noise.read_noise_dn, noise.electrons_per_dn, a, b)


def _hotspots(chi2_map: np.ndarray) -> list[Defect]:
    smooth = ndimage.gaussian_filter(chi2_map, HOTSPOT_SIGMA_PX, mode="nearest")
    med = float(np.median(smooth))
    spread = 1.4826 * float(np.median(np.abs(smooth - med))) + 1e-12
    hot = (smooth > med + HOTSPOT_ROBUST_SIGMAS * spread) & (smooth > med + HOTSPOT_MIN_EXCESS)
    labels, count = ndimage.label(hot)
    out = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        excess = np.where(labels[sl] == k, smooth[sl] - med, 0.0)
        peak = float(excess.max())
        core = excess >= 0.5 * peak  # the defect's half-maximum area within its hotspot
        if core.sum() < 3:
            continue
        rows, cols = np.nonzero(core)
        r0, r1 = sl[0].start + int(rows.min()), sl[0].start + int(rows.max()) + 1
        c0, c1 = sl[1].start + int(cols.min()), sl[1].start + int(cols.max()) + 1
        cy, cx = ndimage.center_of_mass(np.where(core, excess, 0.0))
        h, w = r1 - r0, c1 - c0
        if w <= 3 and h >= 4 * w:
            kind = "column defect"
        elif h <= 3 and w >= 4 * h:
            kind = "row defect"
        else:
            kind = "dust speck"
        out.append(Defect(kind, r0, r1, c0, c1, (sl[0].start + cy, sl[1].start + cx), peak))
    return out


def _blemishes(recording: Recording, collection: SlitCollection, sm: SystemMatrices, saturation: float,
               noise: NoiseEstimate, defects: list[Defect], names: list[str]) -> list[Defect]:
    """Soft shadows found in the flat and validation frames (:mod:`~thintact_sdk.calibration.blemish`)
    as defects; one where a located dust speck already is adds its depth and width to it."""
    frames = (_residual(recording, i, collection, sm, saturation)[1:] for i in collection.validation)
    found = find_blemishes(ratio_map(frames, noise.variance, sm.sensor_shape))
    out = []
    for b in found:
        note = f"(σ {b.sigma_px:.1f} px, {b.z:.0f} standard deviations; threshold {b.threshold_z:.1f})"
        speck = next((d for d in defects if d.kind == "dust speck"
                      and (d.centre[0] - b.row) ** 2 + (d.centre[1] - b.col) ** 2 <= (1.5 * b.sigma_px) ** 2), None)
        if speck is not None:
            speck.note = f"its shadow {100 * b.depth:.1f} % deep, σ {b.sigma_px:.1f} px"
            continue
        r0, r1, c0, c1 = b.bounds(sm.sensor_shape)
        out.append(Defect("shading blemish", r0, r1, c0, c1, (b.row, b.col), b.depth, list(names), note=note))
    return out


def _line_deviation(open_matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Relative deviation of each sensor line's open response from its neighbours, and the
    robust spread of that deviation (per channel: ``C × lines``, ``C``)."""
    resp = np.abs(np.asarray(open_matrix, np.float64).sum(axis=2))  # C × lines
    trend = ndimage.median_filter(resp, size=(1, 7), mode="nearest")
    dev = resp / np.where(trend > 0, trend, 1.0) - 1.0
    spread = 1.4826 * np.median(np.abs(dev - np.median(dev, axis=1, keepdims=True)), axis=1)
    return dev, spread


def _lines(dev: np.ndarray, spread: np.ndarray, names: list[str], axis: str,
           shape: tuple[int, int]) -> list[Defect]:
    out: dict[int, Defect] = {}
    for c in range(dev.shape[0]):
        bad = np.flatnonzero((np.abs(dev[c]) > LINE_ROBUST_SIGMAS * spread[c])
                             & (np.abs(dev[c]) > LINE_MIN_DEVIATION))
        for j in (int(b) for b in bad):
            kind = ("dim " if dev[c, j] < 0 else "bright ") + axis
            if j not in out:
                if axis == "column":
                    out[j] = Defect(kind, 0, shape[0], j, j + 1, (shape[0] / 2, float(j)), float(dev[c, j]))
                else:
                    out[j] = Defect(kind, j, j + 1, 0, shape[1], (float(j), shape[1] / 2), float(dev[c, j]))
            out[j].channels.append(names[c] if c < len(names) else str(c))
    return list(out.values())


def _in_ghost_edge(d: Defect, dy: int, dx: int, shape: tuple[int, int]) -> bool:
    """A residual hotspot inside the band along the sensor edge where a ghost displaced by
    ``(dy, dx)`` has no copy (its source lies beyond the sensor): the ghost's, not a defect."""
    if d.kind not in ("dust speck", "column defect", "row defect"):
        return False
    rows = (d.row1 <= dy) if dy > 0 else (d.row0 >= shape[0] + dy) if dy < 0 else False
    cols = (d.col1 <= dx) if dx > 0 else (d.col0 >= shape[1] + dx) if dx < 0 else False
    return bool(rows or cols)


def _kept_lines(defects: list[Defect], shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Sensor rows and columns (boolean) clear of the located ``defects``, each widened by half
    its size (the half-maximum box is the core only)."""
    keep_rows, keep_cols = np.ones(shape[0], bool), np.ones(shape[1], bool)
    for d in defects:
        hr, hc = (d.row1 - d.row0) // 2 + 1, (d.col1 - d.col0) // 2 + 1
        if d.kind.endswith("row") or d.kind == "dust speck" or d.kind == "row defect":
            keep_rows[max(d.row0 - hr, 0) : d.row1 + hr] = False
        if d.kind.endswith("column") or d.kind == "dust speck" or d.kind == "column defect":
            keep_cols[max(d.col0 - hc, 0) : d.col1 + hc] = False
    return keep_rows, keep_cols


class SlitFrames:
    """The recording's slit frames, taken from the recording (its kept frames, each file read
    once per :class:`~thintact_sdk.formats.recording.Recording`) on every iteration.

    Iterating yields ``(signal, horizontal)`` per slit frame: its ``R × S × C`` signal (DN above
    dark at the reference exposure, float64) and whether it is a horizontal slit. Only one
    frame is held at a time, so the ghost search's :func:`~thintact_sdk.calibration.ghost.exact_strength`
    runs in one frame's memory however many slits the recording has.
    """

    def __init__(self, recording: Recording, indices: list[int], horizontal: list[bool],
                 dark_dn: np.ndarray, exposure_us: float | None, channels: int) -> None:
        self.recording = recording
        self.indices = list(indices)
        self.horizontal = list(horizontal)
        self.dark_dn = dark_dn
        self.exposure_us = exposure_us
        self.channels = channels

    def __len__(self) -> int:
        return len(self.indices)

    def __iter__(self) -> Iterator[tuple[np.ndarray, bool]]:
        for i, horizontal in zip(self.indices, self.horizontal, strict=True):
            signal, _ = signal_of(self.recording, i, self.dark_dn, self.exposure_us)
            yield signal[..., : self.channels], horizontal


def _slit_indices(recording: Recording) -> tuple[list[int], list[bool], int]:
    """Slit frames (indices, horizontal?) and the number of dark frames, from the scenes alone."""
    indices: list[int] = []
    horizontal: list[bool] = []
    dark_frames = 0
    for i in range(len(recording)):
        scene = recording.scene(i)
        if scene is None:
            continue
        roles = classify_scene(scene)
        dark_frames += int(is_dark(roles))
        if is_slit(roles):
            indices.append(i)
            horizontal.append(any(r.kind == "hslit" for r in roles))
    return indices, horizontal, dark_frames


def _forward_lit(sm: SystemMatrices, x: np.ndarray) -> np.ndarray:
    """``sm.forward(x)`` (``N × M × C`` → ``C × R × S`` DN, float64, channel first: each
    channel's plane contiguous) with the products taken over the scene's lit rows (or columns,
    whichever are fewer) only and ordered to be cheapest: ``P[:, rows] (X[rows] Qᵀ)`` or
    ``(P X[:, cols]) Q[:, cols]ᵀ``. For a slit that is ``R·S`` operations per term instead of
    ``R·N·M + R·M·S``; the same values to rounding."""
    c = x.shape[2]
    out = np.empty((c, *sm.sensor_shape))
    for ch in range(c):
        xc = np.asarray(x[..., ch], np.float64)
        lit = xc != 0
        rows, cols = np.flatnonzero(lit.any(axis=1)), np.flatnonzero(lit.any(axis=0))
        for t, (pm, qm) in enumerate(((sm.Po, sm.Qo), (sm.Pc, sm.Qc))):
            p, q = pm[ch if pm.shape[0] > 1 else 0], qm[ch if qm.shape[0] > 1 else 0]
            term = p[:, rows] @ (xc[rows] @ q.T) if len(rows) <= len(cols) else (p @ xc[:, cols]) @ q[:, cols].T
            if t == 0:
                out[ch] = term
            else:
                out[ch] += term
    return out


def _lit_at(sm: SystemMatrices, x: np.ndarray, rr: np.ndarray, ss: np.ndarray, cc: np.ndarray) -> np.ndarray:
    """:func:`_forward_lit` at the sensor entries ``(rr[k], ss[k], cc[k])`` only (DN, float64):
    the lit rows' (or columns') factors at those pixels, ``O(K·lit)`` operations for ``K``
    entries instead of a whole frame."""
    out = np.zeros(len(rr))
    for ch in range(x.shape[2]):
        at = np.flatnonzero(cc == ch)
        if at.size == 0:
            continue
        xc = np.asarray(x[..., ch], np.float64)
        lit = xc != 0
        rows, cols = np.flatnonzero(lit.any(axis=1)), np.flatnonzero(lit.any(axis=0))
        r_at, s_at = rr[at], ss[at]
        for pm, qm in ((sm.Po, sm.Qo), (sm.Pc, sm.Qc)):
            p, q = pm[ch if pm.shape[0] > 1 else 0], qm[ch if qm.shape[0] > 1 else 0]
            if len(rows) <= len(cols):
                right = xc[rows] @ q.T  # lit rows × S
                out[at] += np.einsum("kj,jk->k", p[np.ix_(r_at, rows)], right[:, s_at])
            else:
                left = p @ xc[:, cols]  # R × lit columns
                out[at] += np.einsum("kj,kj->k", left[r_at], q[np.ix_(s_at, cols)])
    return out


def _residual_cf(recording: Recording, i: int, collection: SlitCollection, sm: SystemMatrices,
                 saturation: float) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """Slit frame ``i``: its label, residual and prediction (``C × R × S`` DN, float64, channel
    first, the exposure scaling undone) and the unsaturated pixels (boolean, same shape)."""
    c = sm.channels
    scene = recording.scene(i)
    if scene is None:  # the recording changed under us: slit frames are classified by their scene
        raise CalibrationError(f"{recording.root}: frame {i} has no scene any more")
    raw = np.asarray(recording.measurement(i))
    raw = raw[..., None] if raw.ndim == 2 else raw
    pred = _forward_lit(sm, scene_for_channels(scene, c))
    scale = exposure_scale(recording, i, collection.exposure_us)
    res = np.empty_like(pred)
    ok = np.empty(pred.shape, bool)
    for ch in range(c):
        res[ch] = raw[..., ch]
        res[ch] -= collection.dark_dn[..., ch]
        if scale != 1.0:
            res[ch] *= scale
        res[ch] -= pred[ch]
        np.less(raw[..., ch], saturation, out=ok[ch])
    label = recording.frames[i].label or str(i)
    return label, res / scale, pred / scale, ok


def _residual(recording: Recording, i: int, collection: SlitCollection, sm: SystemMatrices,
              saturation: float) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_residual_cf` as ``R × S × C`` views (label, residual, prediction, unsaturated)."""
    label, res, pred, ok = _residual_cf(recording, i, collection, sm, saturation)
    return label, np.moveaxis(res, 0, 2), np.moveaxis(pred, 0, 2), np.moveaxis(ok, 0, 2)


def _sampled_residual(recording: Recording, i: int, collection: SlitCollection, sm: SystemMatrices,
                      saturation: float, pick: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Prediction and residual (DN, exposure scaling undone) of slit frame ``i`` at the flat
    ``C × R × S`` entries ``pick``, its saturated entries left out: what :func:`_residual_cf`
    gives there, without computing the rest of the frame."""
    scene = recording.scene(i)
    if scene is None:
        raise CalibrationError(f"{recording.root}: frame {i} has no scene any more")
    r, s = sm.sensor_shape
    cc, rest = np.divmod(pick, r * s)
    rr, ss = np.divmod(rest, s)
    raw = np.asarray(recording.measurement(i))
    raw = raw[..., None] if raw.ndim == 2 else raw
    got = raw[rr, ss, cc].astype(np.float64)
    keep = got < saturation
    rr, ss, cc, got = rr[keep], ss[keep], cc[keep], got[keep]
    scale = exposure_scale(recording, i, collection.exposure_us)
    pred = _lit_at(sm, scene_for_channels(scene, sm.channels), rr, ss, cc)
    res = (got - collection.dark_dn[rr, ss, cc]) * scale - pred
    return pred / scale, res / scale


class _LitForward32:
    """:func:`_forward_lit` one channel at a time in float32 (``R × S``): both terms in one
    ``R × 2k`` by ``2k × S`` product over the scene's ``k`` lit rows (or columns). A slit
    frame of thousands of DN against noise of a few DN loses nothing to float32 in a χ² map,
    and a channel plane in float32 stays in the last-level cache where the whole frame in
    float64 does not."""

    def __init__(self, sm: SystemMatrices) -> None:
        def pick(m: np.ndarray, ch: int) -> np.ndarray:
            return np.asarray(m[ch if m.shape[0] > 1 else 0], np.float32)

        self.p = [(pick(sm.Po, ch), pick(sm.Pc, ch)) for ch in range(sm.channels)]
        self.q = [(pick(sm.Qo, ch), pick(sm.Qc, ch)) for ch in range(sm.channels)]

    def __call__(self, xc: np.ndarray, ch: int) -> np.ndarray:
        """Channel ``ch``'s prediction (DN, float32 ``R × S``) of its scene plane ``xc``."""
        xc = np.asarray(xc, np.float32)
        lit = xc != 0
        rows, cols = np.flatnonzero(lit.any(axis=1)), np.flatnonzero(lit.any(axis=0))
        (po, pc), (qo, qc) = self.p[ch], self.q[ch]
        if len(rows) <= len(cols):
            x = xc[rows]
            return np.hstack([po[:, rows], pc[:, rows]]) @ np.vstack([x @ qo.T, x @ qc.T])
        x = xc[:, cols]
        return np.hstack([po @ x, pc @ x]) @ np.vstack([qo[:, cols].T, qc[:, cols].T])


def _chi2_pass(recording: Recording, indices: list[int], collection: SlitCollection, sm: SystemMatrices,
               saturation: float, noise: NoiseEstimate) -> tuple[np.ndarray, dict[str, float]]:
    """Pass 2: the χ² map (``R × S``, float64: each pixel's mean of ``r²/σ²`` over the slit
    frames and channels where it is unsaturated) and each slit frame's mean χ², with the
    measured noise. Per frame and channel in float32 planes, in place (what
    :func:`_residual_cf` gives, to float32 rounding)."""
    c, shape = sm.channels, sm.sensor_shape
    forward = _LitForward32(sm)
    dark = [np.asarray(collection.dark_dn[..., ch], np.float32) for ch in range(c)]
    offset, slope = np.float32(noise.variance_offset_dn2), np.float32(noise.variance_slope)
    chi2_sum = np.zeros(shape)
    saturated = np.zeros(shape, np.int32)
    z, var = np.empty(shape, np.float32), np.empty(shape, np.float32)
    bad = np.empty(shape, bool)
    slit_chi2: dict[str, float] = {}
    for i in indices:
        scene = recording.scene(i)
        if scene is None:  # the recording changed under us: slit frames are classified by their scene
            raise CalibrationError(f"{recording.root}: frame {i} has no scene any more")
        raw = np.asarray(recording.measurement(i))
        raw = raw[..., None] if raw.ndim == 2 else raw
        x = scene_for_channels(scene, c)
        unscale = np.float32(1.0 / exposure_scale(recording, i, collection.exposure_us))
        z_sum, m_sum = 0.0, 0
        for ch in range(c):
            pred = forward(x[..., ch], ch)
            if unscale != 1.0:
                pred *= unscale  # the prediction at this frame's exposure
            np.subtract(raw[..., ch], dark[ch], out=z, dtype=np.float32)
            z -= pred
            np.multiply(z, z, out=z)
            np.clip(pred, 0.0, None, out=var)
            var *= slope
            var += offset
            z /= var
            np.greater_equal(raw[..., ch], saturation, out=bad)
            np.copyto(z, np.float32(0.0), where=bad)
            chi2_sum += z
            saturated += bad
            z_sum += float(z.sum(dtype=np.float64))
            m_sum += z.size - int(np.count_nonzero(bad))
        slit_chi2[recording.frames[i].label or str(i)] = z_sum / max(m_sum, 1)
    count = c * len(indices) - saturated
    return chi2_sum / np.maximum(count, 1), slit_chi2


def _noise_samples(recording: Recording, indices: list[int], collection: SlitCollection,
                   sm: SystemMatrices, saturation: float) -> tuple[np.ndarray, np.ndarray]:
    """Pass 1: the prediction and ``r²`` of the unsaturated slit-frame pixels the noise fit uses.

    All of them while the slit frames hold at most ``NOISE_FIT_CAP`` entries (pixels ×
    channels); above it ``⌈NOISE_FIT_CAP / slits⌉`` entries of each frame drawn at random
    (without replacement, seed ``NOISE_FIT_SEED``; the saturated among them left out) and only
    those computed, so memory and time stay bounded by the cap whatever the frame size.
    """
    r, s = sm.sensor_shape
    entries = r * s * sm.channels
    total = len(indices) * entries
    per_frame = None if total <= NOISE_FIT_CAP else -(-NOISE_FIT_CAP // max(len(indices), 1))
    rng = np.random.default_rng(NOISE_FIT_SEED)
    size = total if per_frame is None else per_frame * len(indices)
    # filled in place (no second copy to concatenate), in float32: the fit takes quantiles,
    # medians and bin means of them (float64 sums), for which 7 digits are ample; at the cap
    # that is 160 MB less than float64 beside the rest of the calibration
    preds, r2s = np.empty(size, np.float32), np.empty(size, np.float32)
    n = 0
    for i in indices:
        if per_frame is None:
            _, res, pred, ok = _residual_cf(recording, i, collection, sm, saturation)
            p, e = pred[ok], res[ok]
        else:
            p, e = _sampled_residual(recording, i, collection, sm, saturation,
                                     np.sort(rng.choice(entries, min(per_frame, entries), replace=False)))
        preds[n : n + p.size] = p
        r2s[n : n + p.size] = e**2
        n += p.size
    return preds[:n], r2s[:n]


def measure_noise(recording: Recording, collection: SlitCollection, sm: SystemMatrices,
                  frames_averaged: int) -> NoiseEstimate:
    """The unit's noise from its slit frames: :func:`assess`'s first pass alone (what the
    τ selection needs), so the rest of the health check can run beside the selection."""
    with blas_threads(1):
        indices, _horizontal, dark_frames = _slit_indices(recording)
        if not indices:
            raise CalibrationError(f"{recording.root}: no slit frame to judge the unit's health by")
        saturation = recording.profile.noise.saturation_dn - 1.0
        pred_all, r2_all = _noise_samples(recording, indices, collection, sm, saturation)
        from_frames = "dark frame" in collection.dark_source
        return _fit_noise(pred_all, r2_all, recording.profile.noise, max(1, int(frames_averaged)),
                          dark_frames if from_frames else 0)


def assess(recording: Recording, collection: SlitCollection, sm: SystemMatrices,
           frames_averaged: int, noise: NoiseEstimate | None = None) -> HealthReport:
    """Residuals of every slit frame against the calibrated model; noise; defects.

    The slit frames are streamed from the recording, never held together: pass 1 gathers what
    the noise fit needs (:func:`_noise_samples`, bounded by ``NOISE_FIT_CAP``), pass 2 takes each
    frame again, recomputes its prediction and adds it to the χ² map, and the ghost search
    takes them a third time (:class:`SlitFrames`); every pass gets the recording's kept frame
    (each file is read once). Memory: a few frames' float64 signals plus the noise-fit entries,
    independent of the number of slits (the recording maps its frames beyond a small budget,
    :data:`~thintact_sdk.formats.recording.HELD_BYTES`).

    Parameters
    ----------
    recording, collection
        The recording and what :func:`~thintact_sdk.calibration.collect.collect_slits` made of it.
    sm
        The calibrated matrices (DN above dark per display unit at the reference exposure).
    frames_averaged
        Frames averaged per pattern (the noise of the measurements is divided by it).
    noise
        The noise :func:`measure_noise` measured on the same frames (its pass is then skipped).

    OpenBLAS is held at one thread throughout: the products are small (one frame's
    prediction is ``R × N`` by ``N × M`` by ``M × S``) and on a busy host two threads only
    spin-wait for each other (many times slower).
    """
    with blas_threads(1):
        return _assess(recording, collection, sm, frames_averaged, noise)


def _assess(recording: Recording, collection: SlitCollection, sm: SystemMatrices,
            frames_averaged: int, noise: NoiseEstimate | None) -> HealthReport:
    profile = recording.profile
    nz = profile.noise
    k = max(1, int(frames_averaged))
    c = sm.channels
    shape = sm.sensor_shape
    saturation = nz.saturation_dn - 1.0
    indices, horizontal, dark_frames = _slit_indices(recording)
    if not indices:
        raise CalibrationError(f"{recording.root}: no slit frame to judge the unit's health by")
    if noise is None:
        pred_all, r2_all = _noise_samples(recording, indices, collection, sm, saturation)
        from_frames = "dark frame" in collection.dark_source
        noise = _fit_noise(pred_all, r2_all, nz, k, dark_frames if from_frames else 0)
        del pred_all, r2_all
    chi2_map, slit_chi2 = _chi2_pass(recording, indices, collection, sm, saturation, noise)
    slit_frames = SlitFrames(recording, indices, horizontal, collection.dark_dn, collection.exposure_us, c)
    names = list(profile.sensor.channels)
    col_dev, col_spread = _line_deviation(sm.Qo)
    row_dev, row_spread = _line_deviation(sm.Po)
    defects = _hotspots(chi2_map)
    for d in defects:
        d.channels = names[:c]
    defects += _lines(col_dev, col_spread, names, "column", shape)
    defects += _lines(row_dev, row_spread, names, "row", shape)
    ghosts, scans = find_ghosts(collection.channels, sm, profile, *_kept_lines(defects, shape), slit_frames)
    if ghosts:  # (at most one) its edge: where the copy comes in from beyond the sensor, not dust
        inside = [d for d in defects if not _in_ghost_edge(d, ghosts[0].rows, ghosts[0].cols, shape)]
        if len(inside) < len(defects):
            # searched again with those lines in: left out, they cut the copy's source lines
            # off the fit (a 10 % ghost at (6, -9) read 7.6 % with them out, 10.2 % in)
            again, scans_again = find_ghosts(collection.channels, sm, profile, *_kept_lines(inside, shape),
                                             slit_frames)
            if again:
                ghosts, scans = again, scans_again
                inside = [d for d in defects if not _in_ghost_edge(d, again[0].rows, again[0].cols, shape)]
        defects = inside
    pitch = profile.sensor.pixel_pitch_um
    for g in ghosts:
        how = ("separable: the matrices absorbed it, every reconstruction carries it" if g.separable
               else "not separable: it raises the slit residuals")
        defects.append(Defect("ghost", 0, shape[0], 0, shape[1], (shape[0] / 2, shape[1] / 2), g.strength,
                              names[:c], (g.rows, g.cols),
                              f"({g.rows * pitch:+.0f}, {g.cols * pitch:+.0f} um; {how})"))
    defects += _blemishes(recording, collection, sm, saturation, noise, defects, names[:c])
    return HealthReport(slit_chi2, chi2_map, noise, defects, col_dev, row_dev, scans)
