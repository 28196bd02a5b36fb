"""The mask's pose from one flat-field capture: offset, rotation (small angles and 180° flips),
magnification.

A uniformly lit scene gives ``Y = (Po·1)(Qo·1)ᵀ + (Pc·1)(Qc·1)ᵀ``: along each axis the image
lies in the span of the open profile ``Po·1`` and the coding profile ``Pc·1``, which is the
known φ seen through the geometry (direct generation, :mod:`thintact_sdk.imaging.direct_generation`).
For each axis the pose is the one whose two profiles best span the measured image's leading
singular vectors (a 1-D search over the shift, for both orientations of φ and a few
scene-to-mask distances, then a parabolic refinement). A 180° flip reverses φ along both axes.

A small rotation turns the pattern's x-shift into a linear function of the mask's y
(``m'ₓ ≈ mₓ − dx + θ·m_y``): the column shift fitted on horizontal bands of sensor rows,
against the band's mask-plane y, has slope θ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from thintact_sdk.errors import CalibrationError
from thintact_sdk.imaging.direct_generation import AxisGeometry, DirectGenerator
from thintact_sdk.profile import Profile

BANDS = 6
"""Horizontal bands of sensor rows on which the column shift is fitted for the rotation."""


@dataclass
class PoseEstimate:
    """Where the mask is.

    Attributes
    ----------
    dx_um, dy_um
        Shift of the pattern along x (columns) and y (rows), um (``mask_misalignment``).
    angle_deg
        Small rotation, degrees, +x towards +y (``mask_misalignment``).
    flipped
        The mask is turned by 180° (φ and φ_rows reversed).
    scene_to_mask_mm
        Scene-to-mask distance z that best explains the shadow's scale (magnification H/z).
    fit
        Fraction of the flat field's two leading singular directions explained per axis (1 = exact).
    """

    dx_um: float
    dy_um: float
    angle_deg: float
    flipped: bool
    scene_to_mask_mm: float
    fit: dict[str, float]

    def apply(self, profile: Profile) -> Profile:
        """``profile`` with this pose: φ reversed when flipped, ``physics`` updated."""
        data = profile.contract_dict()
        if self.flipped:
            data["mask"]["phi"] = list(reversed(profile.mask.phi))
            data["mask"]["phi_rows"] = list(reversed(profile.mask.rows_vector))
        physics = dict(data.get("physics", {}))
        physics["mask_misalignment"] = {"angle_deg": round(self.angle_deg, 5), "dx_um": round(self.dx_um, 3),
                                        "dy_um": round(self.dy_um, 3)}
        geometry = dict(physics.get("geometry", {}))
        geometry["scene_to_mask_mm"] = round(self.scene_to_mask_mm, 5)
        physics["geometry"] = geometry
        data["physics"] = physics
        out = Profile.model_validate(data)
        out._source = profile.source
        return out

    def to_json(self) -> dict[str, Any]:
        return {"dx_um": round(self.dx_um, 3), "dy_um": round(self.dy_um, 3),
                "angle_deg": round(self.angle_deg, 5), "flipped": self.flipped,
                "scene_to_mask_mm": round(self.scene_to_mask_mm, 5),
                "fit": {k: round(v, 6) for k, v in self.fit.items()}}


def _profiles(axis: AxisGeometry, phi: np.ndarray) -> np.ndarray:
    """``n_sensor × 2``: open and coding profile of a uniform scene along ``axis``."""
    gen = DirectGenerator(axis)
    ones = np.ones(axis.n_scene)
    return np.stack([gen.open() @ ones, gen.coding(phi) @ ones], axis=1)


def _score(basis: np.ndarray, target: np.ndarray) -> float:
    """Fraction of ``target``'s columns (orthonormal) inside span(``basis``)."""
    q, _ = np.linalg.qr(basis)
    return float(np.sum((q.T @ target) ** 2) / np.sum(target**2))


def _search(axis: AxisGeometry, phi: np.ndarray, target: np.ndarray, max_shift_um: float,
            step_um: float) -> tuple[float, float]:
    """Best shift (um) and its score; coarse grid then a parabola through the best three."""
    shifts = np.arange(-max_shift_um, max_shift_um + step_um / 2, step_um)
    scores = np.array([_score(_profiles(replace(axis, mask_shift_um=float(s)), phi), target) for s in shifts])
    k = int(np.argmax(scores))
    best, value = float(shifts[k]), float(scores[k])
    for _ in range(3):  # refine: a 4× finer step around the best, three times
        step_um /= 4.0
        local = best + step_um * np.arange(-4, 5)
        vals = [_score(_profiles(replace(axis, mask_shift_um=float(s)), phi), target) for s in local]
        j = int(np.argmax(vals))
        best, value = float(local[j]), float(vals[j])
        if 0 < j < len(local) - 1:
            y0, y1, y2 = vals[j - 1], vals[j], vals[j + 1]
            den = y0 - 2 * y1 + y2
            if den < 0:
                best += 0.5 * step_um * (y0 - y2) / den
    return best, value


def estimate_pose(flat_dn: np.ndarray, profile: Profile, *, z_range: float = 0.06, z_steps: int = 7,
                  bands: int = BANDS) -> PoseEstimate:
    """Estimate the mask's pose from a flat field.

    Parameters
    ----------
    flat_dn
        ``R × S`` or ``R × S × C`` signal of a uniform scene, DN above black.
    profile
        The device profile (its nominal geometry, φ, φ_rows; its ``physics`` is ignored).
    z_range, z_steps
        Scene-to-mask distances tried: nominal × (1 ± ``z_range``) in ``z_steps`` steps.
    bands
        Horizontal bands for the rotation fit.
    """
    y = np.asarray(flat_dn, np.float64)
    if y.ndim == 3:
        y = y.mean(axis=2)
    if y.shape != (profile.sensor.rows, profile.sensor.cols):
        raise CalibrationError(f"flat field is {y.shape[0]}×{y.shape[1]} but profile {profile.name!r} has a "
                               f"{profile.sensor.rows}×{profile.sensor.cols} sensor")
    if not np.all(np.isfinite(y)) or float(np.mean(y)) <= 0:
        raise CalibrationError("the flat field has no positive signal above black: light the sensor uniformly")
    nominal = profile.with_physics({})
    u, _, vt = np.linalg.svd(y, full_matrices=False)
    rows_target, cols_target = u[:, :2], vt[:2].T
    phi = np.asarray(profile.mask.phi, float)
    phi_rows = np.asarray(profile.mask.rows_vector, float)
    delta = profile.mask.feature_um
    max_shift = profile.mask.K * delta / 4.0
    z0 = profile.geometry.scene_to_mask_mm

    def fit(flip: bool, z: float) -> tuple[float, float, float, float, float]:
        pr, pc_ = (phi_rows[::-1], phi[::-1]) if flip else (phi_rows, phi)
        dy, s_r = _search(replace(AxisGeometry.rows_of(nominal), z_mm=z), pr, rows_target, max_shift, delta / 2)
        dx, s_c = _search(replace(AxisGeometry.cols_of(nominal), z_mm=z), pc_, cols_target, max_shift, delta / 2)
        return s_r + s_c, dx, dy, s_r, s_c

    zs = z0 * np.linspace(1 - z_range, 1 + z_range, z_steps)
    trials = {(flip, float(z)): fit(flip, float(z)) for flip in (False, True) for z in zs}
    flipped_f, z = max(trials, key=lambda key: trials[key][0])
    k = int(np.argmin(np.abs(zs - z)))
    if 0 < k < len(zs) - 1:  # parabola through the three best distances
        y0, y1, y2 = (trials[(flipped_f, float(zs[i]))][0] for i in (k - 1, k, k + 1))
        den = y0 - 2 * y1 + y2
        if den < 0:
            z = float(z + 0.5 * (zs[1] - zs[0]) * (y0 - y2) / den)
    _, dx, dy, s_r, s_c = fit(flipped_f, z)
    flipped = bool(flipped_f)
    pc_ = phi[::-1] if flipped else phi
    ax_c = replace(AxisGeometry.cols_of(nominal), z_mm=z)
    # rotation: the column shift of horizontal bands against the band's mask-plane y; each
    # band's profile is the known mixture (row profiles summed over the band) of the columns'
    # open and coding profiles, so only the shift and one gain are free
    ax_r = replace(AxisGeometry.rows_of(nominal), z_mm=z, mask_shift_um=dy)
    row_profiles = _profiles(ax_r, phi_rows[::-1] if flipped else phi_rows)
    edges = np.linspace(0, y.shape[0], bands + 1).astype(int)
    h = z + profile.geometry.mask_to_sensor_mm
    ys, shifts = [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        weights = row_profiles[a:b].sum(axis=0)
        shifts.append(_band_shift(ax_c, pc_, y[a:b].sum(axis=0), weights, dx, delta))
        centre_um = ((a + b - 1) / 2 - (y.shape[0] - 1) / 2) * profile.sensor.pixel_pitch_um
        ys.append(centre_um * z / h)
    slopes = [(shifts[j] - shifts[i]) / (ys[j] - ys[i]) for i in range(bands) for j in range(i + 1, bands)]
    slope = float(np.median(slopes))  # Theil–Sen: d(shift)/d(m_y) = −θ
    angle = -math.degrees(math.atan(slope))
    return PoseEstimate(dx, dy, angle, flipped, z, {"rows": s_r, "cols": s_c})


def _band_shift(axis: AxisGeometry, phi: np.ndarray, band: np.ndarray, weights: np.ndarray,
                around_um: float, delta: float) -> float:
    """Column shift (um) of one band of rows whose profile is ``weights @ [open, coding]ᵀ``,
    searched within ± half a cell of the global estimate."""
    shifts = around_um + delta * np.linspace(-0.5, 0.5, 41)
    unit = band / np.linalg.norm(band)
    scores = []
    for sh in shifts:
        model = _profiles(replace(axis, mask_shift_um=float(sh)), phi) @ weights
        scores.append(float(unit @ model) ** 2 / float(model @ model))
    j = int(np.argmax(scores))
    best = float(shifts[j])
    if 0 < j < len(shifts) - 1:
        y0, y1, y2 = scores[j - 1], scores[j], scores[j + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            best += 0.5 * (shifts[1] - shifts[0]) * (y0 - y2) / den
    return best
