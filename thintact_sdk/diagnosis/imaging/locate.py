"""Where a residual sits: in space (hotspots), by channel, scene, signal level, radius
from the optical axis and spatial frequency: the imaging axes over the shared statistics of
:mod:`~thintact_sdk.diagnosis.core.residual_axes`.

Inputs are ``F × R × S × C`` arrays: ``z`` the residual in noise units (zero at invalid
pixels), ``valid`` the pixels that count, ``signal_dn`` the predicted signal above black.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_sdk.diagnosis.core.residual_axes import (
    Hotspot,
    Profile1D,
    binned_chi2,
    excess_map,
    find_hotspots,
    mean_z_map,
)


@dataclass
class Location:
    """Everything :func:`locate` finds out about a residual."""

    excess_map: np.ndarray  # R × S, Σ over frames and channels of (z² − 1)
    mean_z_map: np.ndarray  # R × S, mean signed z over frames and channels
    hotspots: list[Hotspot]
    by_channel: np.ndarray  # C, χ² per value
    by_frame: np.ndarray  # F, χ² per value
    by_signal: Profile1D
    by_radius: Profile1D
    by_frequency: Profile1D  # residual power / noise power against spatial frequency
    total_excess: float
    summary: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


def radius_map_mm(rows: int, cols: int, pitch_um: float) -> np.ndarray:
    """``R × S`` distance of each pixel centre from the optical axis, mm (CONTRACTS §1)."""
    y = (np.arange(rows) - (rows - 1) / 2.0) * pitch_um * 1e-3
    x = (np.arange(cols) - (cols - 1) / 2.0) * pitch_um * 1e-3
    return np.hypot(y[:, None], x[None, :])


def frequency_profile(
    residual_dn: np.ndarray, variance_dn2: np.ndarray, valid: np.ndarray, pitch_um: float, n_bins: int = 12
) -> Profile1D:
    """Residual power over noise power against radial spatial frequency (cycles/mm).

    Invalid pixels are zeroed; the noise power of each image is its mean variance over
    valid pixels times the valid fraction, so a white-noise residual gives ≈ 1 at every
    frequency.
    """
    f, r, s, c = residual_dn.shape
    res = np.where(valid, residual_dn, 0.0)
    spec = np.abs(np.fft.rfft2(res, axes=(1, 2))) ** 2 / (r * s)
    noise_p = np.sum(np.where(valid, variance_dn2, 0.0), axis=(1, 2)) / (r * s)  # F × C
    ratio = spec / np.maximum(noise_p[:, None, None, :], 1e-12)
    fy = np.fft.fftfreq(r, d=pitch_um * 1e-3)
    fx = np.fft.rfftfreq(s, d=pitch_um * 1e-3)
    fr = np.hypot(fy[:, None], fx[None, :])
    fmax = 0.5 / (pitch_um * 1e-3)
    edges = np.linspace(0.0, fmax, n_bins + 1)
    mean_ratio = np.mean(ratio, axis=(0, 3))
    prof, cnt = binned_chi2(fr.ravel(), mean_ratio.ravel(), edges)
    return Profile1D("spatial frequency", "cycles/mm", 0.5 * (edges[1:] + edges[:-1]), prof, cnt)


def locate(
    z: np.ndarray,
    valid: np.ndarray,
    signal_dn: np.ndarray,
    residual_dn: np.ndarray,
    variance_dn2: np.ndarray,
    pitch_um: float,
    labels: list[str],
    channels: list[str],
) -> Location:
    """Break a residual down by space, channel, frame, signal level, radius and frequency,
    and describe it in words (:attr:`Location.summary`)."""
    f, r, s, c = z.shape
    z2 = np.where(valid, z * z, 0.0)
    nval = valid.sum(axis=(0, 3)).astype(np.float64)
    exc = excess_map(z, valid)
    mean_z = mean_z_map(z, valid)
    with np.errstate(invalid="ignore", divide="ignore"):
        by_channel = z2.sum(axis=(0, 1, 2)) / np.maximum(valid.sum(axis=(0, 1, 2)), 1)
        by_frame = z2.sum(axis=(1, 2, 3)) / np.maximum(valid.sum(axis=(1, 2, 3)), 1)
    hot = find_hotspots(exc, nval)
    sig = signal_dn[valid]
    top = float(np.percentile(sig, 99.5)) if sig.size else 1.0
    edges = np.linspace(min(0.0, float(sig.min()) if sig.size else 0.0), max(top, 1.0), 11)
    sp, scnt = binned_chi2(sig, z2[valid], edges)
    by_signal = Profile1D("signal level", "DN", 0.5 * (edges[1:] + edges[:-1]), sp, scnt)
    rad = np.broadcast_to(radius_map_mm(r, s, pitch_um)[None, :, :, None], z.shape)[valid]
    redges = np.linspace(0.0, float(rad.max()) + 1e-9 if rad.size else 1.0, 9)
    rp, rcnt = binned_chi2(rad, z2[valid], redges)
    by_radius = Profile1D("radius from axis", "mm", 0.5 * (redges[1:] + redges[:-1]), rp, rcnt)
    by_freq = frequency_profile(residual_dn, variance_dn2, valid, pitch_um)
    loc = Location(
        excess_map=exc,
        mean_z_map=mean_z,
        hotspots=hot,
        by_channel=by_channel,
        by_frame=by_frame,
        by_signal=by_signal,
        by_radius=by_radius,
        by_frequency=by_freq,
        total_excess=float(np.sum(exc)),
    )
    loc.summary = describe_location(loc, labels, channels, (r, s))
    return loc


def _trend(p: Profile1D) -> str:
    y = p.chi2
    ok = np.isfinite(y) & (p.counts > 50)
    if ok.sum() < 3:
        return "flat"
    yy = y[ok]
    lo, hi = float(np.mean(yy[: max(1, len(yy) // 3)])), float(np.mean(yy[-max(1, len(yy) // 3) :]))
    if hi > 1.5 * lo and hi - lo > 0.3:
        return "rising"
    if lo > 1.5 * hi and lo - hi > 0.3:
        return "falling"
    return "flat"


def describe_location(
    loc: Location, labels: list[str], channels: list[str], shape: tuple[int, int]
) -> str:
    """Plain-words summary of where the excess χ² sits."""
    n_val = float(np.sum(loc.by_signal.counts))
    chi2 = 1.0 + loc.total_excess / max(n_val, 1.0)
    if chi2 < 1.05:
        return (
            f"The residual matches the noise model (χ²/dof {chi2:.3f}); no excess to locate."
        )
    parts = [f"χ²/dof {chi2:.2f}: the residual is {np.sqrt(chi2):.2f}× the noise."]
    if loc.hotspots:
        area = sum((h.row1 - h.row0) * (h.col1 - h.col0) for h in loc.hotspots)
        share = sum(h.share for h in loc.hotspots)
        frac = area / float(shape[0] * shape[1])
        if frac > 0.5:
            parts.append(f"It is spread over the sensor ({share:.0%} of the excess in {frac:.0%} of it).")
        else:
            h = loc.hotspots[0]
            parts.append(
                f"{share:.0%} of the excess lies in {len(loc.hotspots)} region(s) covering "
                f"{frac:.1%} of the sensor; the largest is rows {h.row0}-{h.row1}, "
                f"columns {h.col0}-{h.col1} ({h.share:.0%})."
            )
    else:
        parts.append("No region stands out: the excess is spread evenly over the sensor.")
    ch = loc.by_channel
    if ch.size > 1 and np.nanmax(ch) > 1.3 * np.nanmin(ch):
        parts.append(
            "By channel: " + ", ".join(f"{n} {v:.2f}" for n, v in zip(channels, ch, strict=False)) + "."
        )
    else:
        parts.append("All channels alike.")
    fr = loc.by_frame
    order = np.argsort(-fr)
    if fr.size > 1 and fr[order[0]] > 1.5 * np.median(fr):
        worst = ", ".join(f"{labels[i]} ({fr[i]:.1f})" for i in order[:3])
        parts.append(f"Worst frames: {worst}; median frame χ² {np.median(fr):.2f}.")
    else:
        parts.append("Every frame departs alike.")
    words = {"rising": "grows with", "falling": "falls with", "flat": "hardly changes with"}
    parts.append(f"The excess {words[_trend(loc.by_signal)]} signal level")
    parts.append(f"and {words[_trend(loc.by_radius)]} distance from the axis;")
    fq = loc.by_frequency
    okf = np.isfinite(fq.chi2)
    if okf.any():
        k = int(np.nanargmax(np.where(okf, fq.chi2, -np.inf)))
        parts.append(
            f"its power peaks at {fq.centres[k]:.0f} cycles/mm ({fq.chi2[k]:.1f}× the noise)."
        )
    return " ".join(parts)
