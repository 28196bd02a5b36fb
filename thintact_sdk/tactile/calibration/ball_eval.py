"""Figures of reconstructed ball presses of known radius (shape consistency and depth accuracy).

Annotation-free figures, per press, from the reconstructed depth ``d`` (mm) and slopes:

* **fitted sphere radius**: a sphere fitted (algebraically, all parameters free) to the
  loaded core, the pixels deeper than half the peak (for a rigid ball cap exactly Hertz's
  contact circle). A pipeline that gives back the shape it was calibrated on returns the
  ball radius; caps read too flat return a larger radius.
* **contact radius** ``√(area/π)`` of the contact region that holds the peak (the
  interpreter's: where the membrane wraps the ball, its sink-in skirt left out;
  :mod:`thintact_sdk.tactile.interpretation.contact_region`), against the contact radius a
  ball of radius R pressed to the reconstructed peak depth p must have, ``√(2Rp − p²)``.
  Where the frame's edge cuts the region (only part of it is in view), the radius of the
  circle fitted to its rim away from the edge (:func:`rim_circle`).
  The region is grown by the calibration's ``contact_rim_mm`` (how far its smoothing moves
  the measure inside the rim of the shape it taught; 0 without one).
  ``skirt_radius_mm`` is the radius of the region deeper than the contact threshold that
  holds the peak, the figure reported before (it includes the skirt).
* **ball fit with the radius fixed**: the ball of radius R whose centre and depth best fit
  the reconstructed depth inside the contact region before its growth (where the membrane
  curves as the ball does; least squares on its surface); depth RMS there, within ``0.9·a``
  of the fitted centre (a that region's radius; its rim is smoothed by the elastomer), and
  slope RMS (vector magnitude) there, also where the ball's slope is under 1 (45°,
  ``slope_rms_gentle``). Without a contact region, the rigid cap fitted to the core and its
  contact circle.
* **edge press**: the contact circle (fitted centre, contact radius) reaches the frame's edge.
* **taught contact ratio** (:func:`taught_contact_ratio`, with the calibration's ball model):
  the contact ratio this measure (with the same growth) reads on the shape the calibration
  taught, pressed as deep as the reconstruction's peak. The curvature's sign changes inside
  the rim of a cap smoothed by the elastomer; the growth undoes that on the calibration's own
  presses, so this reads about 1 at their depths (a sink-in shape reads under 1: its contact
  is narrower than a rigid cap's of the same depth); the reconstruction's ratio over this
  one says how much is the reconstruction's own.

With annotated circles (centre, contact radius a_ann), the same RMS figures against the cap of
radius R whose contact circle is the annotated one (press depth ``R − √(R² − a_ann²)``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Protocol

import cv2
import numpy as np
from scipy.ndimage import label
from scipy.optimize import least_squares

from thintact_sdk.tactile.interpretation.contact_region import contact_region, grown
from thintact_sdk.tactile.interpretation.grid import TactileParams

CORE_FRACTION = 0.5
RIM_FRACTION = 0.9
GENTLE_SLOPE = 1.0
"""Ball slopes below this (45°) make the ``slope_rms_gentle`` figure: on GelSight-type gels
the colour change stops growing with the slope about there (docs/tactile.md), so steeper
slopes cannot be told apart from the image and read short."""
EDGE_NEIGHBOURS = 3
"""An edge press is compared with the median of this many interior presses of the most
similar press depth (one press's sphere radius alone varies too much to compare with)."""


@dataclass
class PressFigures:
    """Figures of one reconstructed ball press (mm unless stated; module docstring)."""

    peak_mm: float
    sphere_radius_mm: float
    contact_radius_mm: float
    contact_radius_expected_mm: float
    centre_rc: tuple[float, float]
    press_mm: float
    depth_rms_mm: float
    slope_rms: float
    slope_rms_flat: float
    edge: bool
    skirt_radius_mm: float = float("nan")
    slope_rms_gentle: float = float("nan")
    contact_ratio_taught: float = float("nan")
    annotated_depth_rms_mm: float | None = None
    annotated_slope_rms: float | None = None
    annotated_press_mm: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def fit_sphere(depth_mm: np.ndarray, mm_per_px: float, fraction: float = CORE_FRACTION
               ) -> tuple[float, tuple[float, float]]:
    """``(radius_mm, (row, col))`` of the sphere fitted to the pixels deeper than
    ``fraction`` of the peak (algebraic least squares; ``inf`` when they are too few or
    coplanar)."""
    d = np.asarray(depth_mm, np.float64)
    peak = float(d.max())
    rr, cc = np.nonzero(d > fraction * peak) if peak > 0 else (np.array([]), np.array([]))
    if len(rr) < 6:
        return float("inf"), (float("nan"), float("nan"))
    x, y, z = cc * mm_per_px, rr * mm_per_px, d[rr, cc]
    a = np.c_[2 * x, 2 * y, 2 * z, np.ones_like(x)]
    sol, *_ = np.linalg.lstsq(a, x * x + y * y + z * z, rcond=None)
    r2 = sol[3] + sol[0] ** 2 + sol[1] ** 2 + sol[2] ** 2
    if not np.isfinite(r2) or r2 <= 0:
        return float("inf"), (float("nan"), float("nan"))
    return float(np.sqrt(r2)), (float(sol[1] / mm_per_px), float(sol[0] / mm_per_px))


def ball_cap(shape: tuple[int, int], centre_rc: tuple[float, float], press_mm: float,
             radius_mm: float, mm_per_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Rigid ball cap: ``(depth, grad_x, grad_y, contact_radius_px)``; depth ``N × M`` mm,
    slopes of the sphere (mm per mm; defined inside the contact circle, 0 outside)."""
    rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    x = (cc - centre_rc[1]) * mm_per_px
    y = (rr - centre_rc[0]) * mm_per_px
    r2 = x * x + y * y
    root = np.sqrt(np.clip(radius_mm**2 - r2, 1e-9, None))
    depth = np.clip(root - (radius_mm - press_mm), 0.0, None)
    inside = depth > 0
    gx = np.where(inside, -x / root, 0.0)
    gy = np.where(inside, -y / root, 0.0)
    return depth, gx, gy, contact_radius_of_press(radius_mm, press_mm) / mm_per_px


def fit_ball_fixed_radius(depth_mm: np.ndarray, radius_mm: float, mm_per_px: float,
                          pixels: np.ndarray | None = None
                          ) -> tuple[tuple[float, float], float]:
    """``((row, col), press_mm)`` of the ball of radius ``radius_mm`` that best fits the depth
    (least squares): with ``pixels`` (``N × M`` bool, the contact) its surface
    ``press − R + √(R² − r²)`` on those pixels, else the rigid cap (0 outside its contact
    circle) on the pixels deeper than half the peak."""
    d = np.asarray(depth_mm, np.float64)
    peak = float(d.max())
    surface = pixels is not None and int(pixels.sum()) >= 3
    fitted = pixels if pixels is not None and surface else d > CORE_FRACTION * peak
    rr, cc = np.nonzero(fitted)
    if peak <= 0 or len(rr) < 3:
        r0, c0 = np.unravel_index(int(np.argmax(d)), d.shape)
        return (float(r0), float(c0)), max(peak, 0.0)
    w = d[rr, cc]
    weights = np.clip(w, 1e-9, None)
    start = np.array([np.average(rr, weights=weights), np.average(cc, weights=weights),
                      peak if surface else min(peak, 0.99 * radius_mm)])

    def resid(p: np.ndarray) -> np.ndarray:
        r2 = ((rr - p[0]) ** 2 + (cc - p[1]) ** 2) * mm_per_px**2
        ball = np.sqrt(np.clip(radius_mm**2 - r2, 0.0, None)) - (radius_mm - p[2])
        return (ball if surface else np.clip(ball, 0.0, None)) - w

    # a rigid cap is at most a hemisphere; a ball's surface inside a contact can sit deeper
    # than its radius where the gel sinks in around it
    top = np.inf if surface else radius_mm
    sol = least_squares(resid, start, bounds=([-np.inf, -np.inf, 0.0], [np.inf, np.inf, top]))
    return (float(sol.x[0]), float(sol.x[1])), float(sol.x[2])


def _holding_peak(mask: np.ndarray, depth_mm: np.ndarray) -> np.ndarray:
    """The connected part of ``mask`` that holds the deepest pixel of ``depth_mm`` (none when
    the deepest pixel is outside ``mask``)."""
    deepest = np.unravel_index(int(np.argmax(depth_mm)), depth_mm.shape)
    if not mask[deepest]:
        return np.zeros(mask.shape, bool)
    labels, _ = label(mask)
    return labels == labels[deepest]


def _equivalent_radius_mm(region: np.ndarray, mm_per_px: float) -> float:
    """Radius (mm) of the disc with the area of ``region``: √(area/π)."""
    return float(np.sqrt(float(np.count_nonzero(region)) / np.pi)) * mm_per_px


def read_contact_radius_mm(depth_mm: np.ndarray, mm_per_px: float, threshold_mm: float,
                           smooth_mm: float, rim_mm: float = 0.0) -> float:
    """Radius (mm) the contact measure reads on ``depth_mm``: of the part of its contact
    region (:func:`~thintact_sdk.tactile.interpretation.contact_region.contact_region`,
    grown by ``rim_mm``) that holds the deepest pixel (:func:`_contact_radius_mm`; 0 when
    the deepest pixel is outside it)."""
    region = contact_region(depth_mm, mm_per_px, threshold_mm, smooth_mm, rim_mm)
    return _contact_radius_mm(_holding_peak(region, depth_mm), mm_per_px)


def _contact_radius_mm(contact: np.ndarray, mm_per_px: float) -> float:
    """Radius (mm) of a contact region: of the disc with its area, or, when the frame's edge
    cuts it (its area is only the part in view), of the circle fitted to its rim away from
    the edge (:func:`rim_circle`; the disc's when the rim is too short to fit). 0 for an
    empty region."""
    radius = _equivalent_radius_mm(contact, mm_per_px)
    circle = rim_circle(contact, radius / mm_per_px)
    return radius if circle is None else circle[1] * mm_per_px


def rim_circle(region: np.ndarray, area_radius_px: float
                ) -> tuple[tuple[float, float], float] | None:
    """``((row, col), radius_px)`` of a region cut by the frame's edge (only part of it in
    view): the circle fitted to its rim away from the edge (px; the centre may lie outside
    the frame). Algebraic least squares (Kåsa), refined by the rim pixels' distances to it;
    the radius is the region's boundary's (the rim pixels' centres lie half a pixel inside
    it), as the area's radius is.

    None when the region does not reach the frame's edge (its area and centroid say where it
    is), when that rim is too short to fit (under a quarter of the circle of the area's
    radius ``area_radius_px``, or under 8 pixels), or when the fit is not a circle at least
    as wide as the area implies (at most 4×)."""
    if not (region[0].any() or region[-1].any() or region[:, 0].any() or region[:, -1].any()):
        return None
    inner = cv2.erode(region.astype(np.uint8), np.ones((3, 3), np.uint8),
                      borderType=cv2.BORDER_REPLICATE).astype(bool)
    rim = region & ~inner
    rim[0], rim[-1], rim[:, 0], rim[:, -1] = False, False, False, False
    rr, cc = np.nonzero(rim)
    if len(rr) < max(8.0, 0.25 * 2 * np.pi * area_radius_px):
        return None
    y, x = rr.astype(np.float64), cc.astype(np.float64)
    # x² + y² + D·x + E·y + F = 0 (Kåsa), in coordinates centred on the rim for conditioning
    y0, x0 = float(y.mean()), float(x.mean())
    a = np.stack([x - x0, y - y0, np.ones_like(x)], axis=1)
    b = -((x - x0) ** 2 + (y - y0) ** 2)
    (d, e, f), *_ = np.linalg.lstsq(a, b, rcond=None)
    r2 = (d * d + e * e) / 4.0 - f
    if not (np.isfinite(r2) and r2 > 0):
        return None
    # the algebraic fit reads a short arc's radius short: refine by the points' distances
    def off(v: np.ndarray) -> np.ndarray:
        return np.hypot(y - v[0], x - v[1]) - v[2]

    fit = least_squares(off, [y0 - e / 2.0, x0 - d / 2.0, float(np.sqrt(r2))])
    row, col, radius = (float(v) for v in fit.x)
    radius += 0.5  # the rim pixels' centres lie half a pixel inside the region's boundary
    if not (fit.success and area_radius_px <= radius <= 4.0 * area_radius_px):
        return None
    return (row, col), radius


def contact_radius_of_press(radius_mm: float, press_mm: float) -> float:
    """``√(2Rp − p²)`` (mm): the contact radius of a ball of radius R pressed p deep (p clipped
    to 0..R)."""
    p = min(max(press_mm, 0.0), radius_mm)
    return float(np.sqrt(max(2 * radius_mm * p - p * p, 0.0)))


def press_figures(
    depth_mm: np.ndarray,
    grad_x: np.ndarray,
    grad_y: np.ndarray,
    radius_mm: float,
    mm_per_px: float,
    contact_threshold_mm: float = 0.1,
    annotated: tuple[tuple[float, float], float] | None = None,
    smooth_mm: float = 0.0,
    rim_mm: float = 0.0,
) -> PressFigures:
    """The figures of one press (module docstring).

    Parameters
    ----------
    depth_mm, grad_x, grad_y
        ``N × M`` reconstructed depth (mm) and the slopes it was integrated from.
    radius_mm
        Ball radius.
    annotated
        ``((row, col), contact_radius_px)`` of an annotated contact circle, or None.
    smooth_mm
        The scale at which the contact region reads curvature: the pixel of the grid the
        depth was reconstructed on (default: one pixel of ``depth_mm``).
    rim_mm
        The calibration's ``contact_rim_mm``: the contact region is grown by it.
    """
    d = np.asarray(depth_mm, np.float64)
    peak = float(d.max())
    sphere, _ = fit_sphere(d, mm_per_px)
    # the ball's surface: where the membrane curves as the ball does (the region before its
    # growth, whose rim band the elastomer smooths away from the ball); the contact: grown
    region = contact_region(d, mm_per_px, contact_threshold_mm, smooth_mm)
    surface = _holding_peak(region, d)
    contact = (_holding_peak(grown(region, d, mm_per_px, contact_threshold_mm, rim_mm), d)
               if rim_mm > 0 else surface)
    contact_r = _contact_radius_mm(contact, mm_per_px)
    surface_r = _contact_radius_mm(surface, mm_per_px)
    skirt_r = _equivalent_radius_mm(_holding_peak(d > contact_threshold_mm, d), mm_per_px)
    expected = contact_radius_of_press(radius_mm, peak)
    rr, cc = np.mgrid[0 : d.shape[0], 0 : d.shape[1]]
    nan = float("nan")

    def rms_inside(model: np.ndarray, tx: np.ndarray, ty: np.ndarray, inside: np.ndarray
                   ) -> tuple[float, float, float, float]:
        """Depth RMS, slope RMS, the flat membrane's slope RMS and the slope RMS where the
        model's slope is under :data:`GENTLE_SLOPE`, over ``inside``."""
        if not inside.any():
            return nan, nan, nan, nan
        err = np.hypot(grad_x - tx, grad_y - ty)
        steep = np.hypot(tx, ty)
        gentle = inside & (steep < GENTLE_SLOPE)
        return (float(np.sqrt(np.mean((d - model)[inside] ** 2))),
                float(np.sqrt(np.mean(err[inside] ** 2))),
                float(np.sqrt(np.mean(steep[inside] ** 2))),
                float(np.sqrt(np.mean(err[gentle] ** 2))) if gentle.any() else nan)

    def touches_edge(c: tuple[float, float], a_px: float) -> bool:
        return bool(c[0] - a_px <= 0 or c[1] - a_px <= 0 or c[0] + a_px >= d.shape[0] - 1
                    or c[1] + a_px >= d.shape[1] - 1)

    def against(c: tuple[float, float], pr: float) -> tuple[float, float, float, float, bool]:
        """The figures against the rigid cap of press depth ``pr`` centred at ``c``."""
        cap, tx, ty, a_px = ball_cap(d.shape, c, pr, radius_mm, mm_per_px)
        inside = np.hypot(rr - c[0], cc - c[1]) < RIM_FRACTION * a_px
        return (*rms_inside(cap, tx, ty, inside), bool(inside.any()) and touches_edge(c, a_px))

    if surface.sum() >= 3:  # the ball's surface fitted inside the contact
        centre, press = fit_ball_fixed_radius(d, radius_mm, mm_per_px, surface)
        x = (cc - centre[1]) * mm_per_px
        y = (rr - centre[0]) * mm_per_px
        # inside the contact and on the ball (a reconstructed contact can be wider than it)
        inside = surface & (np.hypot(x, y) < RIM_FRACTION * min(surface_r, radius_mm))
        root = np.sqrt(np.clip(radius_mm**2 - x * x - y * y, 1e-9, None))
        drms, srms, flat, srms_gentle = rms_inside(root - (radius_mm - press), -x / root,
                                                   -y / root, inside)
        edge = touches_edge(centre, contact_r / mm_per_px)
    else:  # no contact resolved: the rigid cap fitted to the core
        centre, press = fit_ball_fixed_radius(d, radius_mm, mm_per_px)
        drms, srms, flat, srms_gentle, edge = against(centre, press)
    out = PressFigures(peak, sphere, contact_r, expected, centre, press, drms, srms, flat,
                       edge, skirt_r, srms_gentle)
    if annotated is not None:
        (ar, ac), a_px = annotated
        a_mm = min(a_px * mm_per_px, radius_mm)
        ann_press = radius_mm - float(np.sqrt(radius_mm**2 - a_mm**2))
        out.annotated_depth_rms_mm, out.annotated_slope_rms, *_ = against((ar, ac), ann_press)
        out.annotated_press_mm = ann_press
    return out


class TaughtShape(Protocol):
    """A ball model as :class:`~thintact_sdk.tactile.calibration.ball_press.BallModel` gives it."""

    def parameters(self, ball_radius_mm: float, reach_mm: float | None = None) -> np.ndarray: ...

    def depth(self, shape: tuple[int, int], center_rc: tuple[float, float], param_mm: float,
              ball_radius_mm: float, params: TactileParams) -> np.ndarray: ...


def _contact_ratio(depth_mm: np.ndarray, radius_mm: float, mm_per_px: float,
                   threshold_mm: float, smooth_mm: float, rim_mm: float) -> float:
    """Contact radius of the region holding the peak over ``√(2Rp − p²)``, p the peak (NaN
    without a peak)."""
    expected = contact_radius_of_press(radius_mm, float(depth_mm.max()))
    if expected <= 0:
        return float("nan")
    return read_contact_radius_mm(depth_mm, mm_per_px, threshold_mm, smooth_mm,
                                  rim_mm) / expected


def taught_contact_ratio(model: TaughtShape, shape: tuple[int, int],
                         centre_rc: tuple[float, float], peak_mm: float, radius_mm: float,
                         mm_per_px: float, blur_mm: float, threshold_mm: float = 0.1,
                         smooth_mm: float = 0.0, rim_mm: float = 0.0) -> float:
    """The contact ratio (module docstring) of the calibration's ball model pressed so that its
    peak, after the elastomer blur (``blur_mm``, σ in mm), is the reconstruction's
    ``peak_mm`` (the deepest the model goes when it cannot), at ``centre_rc`` on an
    ``shape`` grid of ``mm_per_px``: what the measure reads on the shape the calibration
    taught (the contact region grown by ``rim_mm``). NaN without a peak."""
    params = TactileParams(rows=shape[0], cols=shape[1], mm_per_px=mm_per_px,
                           elastomer_sigma_mm=blur_mm)

    def render(param: float) -> np.ndarray:
        return model.depth(shape, centre_rc, param, radius_mm, params)

    grid = model.parameters(radius_mm, float(np.hypot(shape[0], shape[1])) * mm_per_px)
    if not (np.isfinite(peak_mm) and peak_mm > 0 and len(grid)):
        return float("nan")
    lo, hi = 0, len(grid) - 1  # the smoothed peak grows with the parameter: bisection
    while lo < hi:
        mid = (lo + hi) // 2
        if float(render(float(grid[mid])).max()) < peak_mm:
            lo = mid + 1
        else:
            hi = mid
    return _contact_ratio(render(float(grid[lo])), radius_mm, mm_per_px, threshold_mm, smooth_mm,
                          rim_mm)


def summarise(figures: list[PressFigures], radius_mm: float) -> dict[str, Any]:
    """Pack-level figures: median fitted sphere radius and its middle half (and relative to
    ``radius_mm``), median contact-radius ratio (measured / expected), depth and slope RMS
    over the presses (root of the mean of squares), median skirt ratio (the region deeper
    than the contact threshold, measured / expected), median taught contact ratio (``None``
    without one), edge against interior presses (each
    edge press's sphere radius over the median of the ``EDGE_NEIGHBOURS`` interior presses of
    the most similar press depth, minus 1; the median over edge presses)."""
    def rms(vals: list[float | None]) -> float | None:
        v = np.array([x for x in vals if x is not None and np.isfinite(x)], np.float64)
        return float(np.sqrt(np.mean(v**2))) if len(v) else None

    radii = np.array([f.sphere_radius_mm for f in figures])
    ratio = np.array([f.contact_radius_mm / f.contact_radius_expected_mm
                      for f in figures if f.contact_radius_expected_mm > 0])
    skirt = np.array([f.skirt_radius_mm / f.contact_radius_expected_mm
                      for f in figures if f.contact_radius_expected_mm > 0
                      and np.isfinite(f.skirt_radius_mm)])
    taught = np.array([f.contact_ratio_taught for f in figures
                       if np.isfinite(f.contact_ratio_taught)])
    out: dict[str, Any] = {
        "presses": len(figures),
        "ball_radius_mm": radius_mm,
        "sphere_radius_median_mm": float(np.median(radii)),
        "sphere_radius_q25_mm": float(np.percentile(radii, 25)),
        "sphere_radius_q75_mm": float(np.percentile(radii, 75)),
        "contact_ratio_median": float(np.median(ratio)) if len(ratio) else None,
        "skirt_ratio_median": float(np.median(skirt)) if len(skirt) else None,
        "contact_ratio_taught_median": float(np.median(taught)) if len(taught) else None,
        "depth_rms_mm": rms([f.depth_rms_mm for f in figures]),
        "slope_rms": rms([f.slope_rms for f in figures]),
        "slope_rms_flat": rms([f.slope_rms_flat for f in figures]),
        "slope_rms_gentle": rms([f.slope_rms_gentle for f in figures]),
        "peak_mean_mm": float(np.mean([f.peak_mm for f in figures])),
        "edge_presses": int(sum(f.edge for f in figures)),
    }
    if any(f.annotated_depth_rms_mm is not None for f in figures):
        out["annotated_depth_rms_mm"] = rms([f.annotated_depth_rms_mm for f in figures])
        out["annotated_slope_rms"] = rms([f.annotated_slope_rms for f in figures])
        out["annotated_press_mean_mm"] = float(np.mean(
            [f.annotated_press_mm for f in figures if f.annotated_press_mm is not None]))
    edge = [f for f in figures if f.edge]
    inner = [f for f in figures if not f.edge]
    if edge and inner:
        rel = []
        for f in edge:  # the interior presses of most similar fitted press depth
            near = sorted(inner, key=lambda h: abs(h.press_mm - f.press_mm))[:EDGE_NEIGHBOURS]
            rel.append(f.sphere_radius_mm / float(np.median([g.sphere_radius_mm for g in near]))
                       - 1.0)
        out["edge_radius_vs_interior_median"] = float(np.median(rel))
    return out
