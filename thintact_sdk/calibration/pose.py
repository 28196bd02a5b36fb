"""The mask's pose from one flat-field capture: orientation (any quarter turn, mirror images),
residual rotation, offset, magnification.

A uniformly lit scene gives ``Y = (Po·1)(Qo·1)ᵀ + (Pc·1)(Qc·1)ᵀ``: along each axis the image
lies in the span of the open profile ``Po·1`` and the coding profile ``Pc·1``, which is the
known φ seen through the geometry (direct generation, :mod:`thintact_sdk.imaging.direct_generation`).

1. **Turn.** The flat field of a mask turned by ``a`` is separable (rank 2) only when read
   along the mask's own axes: the image turned back by each trial angle in [−45°, 45°) is scored
   by the share of its two leading singular values. The best angle modulo 90° says how far the
   mask is from the nearest of the 8 mountings of :mod:`thintact_sdk.imaging.mask_orientation`;
   beyond :data:`MAX_RESIDUAL_DEG` no separable model holds and the estimate stops there.
2. **Orientation, offset, scale.** For each axis the pose is the one whose two profiles best
   span the measured image's leading singular vectors: a 1-D search over the shift for each
   of the 4 candidate vectors (φ or φ_rows, forward or reversed) per axis, the pair consistent
   with one of the 8 mountings that fits best, then a few scene-to-mask distances.
3. **Residual rotation.** A slightly turned mask reads the pattern at
   ``p_x = cos θ·(m_x − dx) + sin θ·(m_y − dy)``: along each sensor row the column profile is
   the one-axis profile with cells ``δ/cos θ`` shifted by ``dx − tan θ·(m_y − dy)``, ``m_y`` the
   row's mask-plane coordinate (the coupling frozen at the centre of the row's footprint on
   the mask, a few cells wide), and likewise for the columns. Angle, offset and z are fitted
   jointly by least squares on the whole 2-D image against this model, the gains of its open
   and coding halves (smooth in the image, a low-order polynomial each) solved linearly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy import ndimage, optimize

from thintact_sdk.errors import CalibrationError
from thintact_sdk.imaging.direct_generation import AxisGeometry, DirectGenerator
from thintact_sdk.imaging.mask_orientation import ORIENTATIONS, Orientation
from thintact_sdk.profile import Profile

MAX_RESIDUAL_DEG = 3.0
"""Largest turn away from the nearest of the 8 mountings that the estimate accepts, degrees.
The flat-field model freezes the turn's coupling over a footprint of a few cells and direct
generation leaves the turn out; beyond this the pose would be wrong, so it is refused."""

TURN_STEP_DEG = 1.0
"""Step of the separability scan over the turn (refined by a parabola)."""

COARSE_SENSOR_PIXELS = 256
"""The coarse shift grid is scored on every k-th sensor pixel, at most about this many (all of
them on small sensors); the finer grids use every pixel."""

SCAN_MAX_SIDE = 192
"""The separability scan bins the image (a separable operation) to at most this many pixels
along its shorter side."""

ENVELOPE_DEGREE = 4
"""Degree of the 2-D polynomial gain of each half (open, coding) of the flat-field model."""


@dataclass
class PoseEstimate:
    """Where the mask is.

    Attributes
    ----------
    orientation
        How the mask is mounted relative to its design (one of 8; written into the profile
        as rewritten ``phi`` / ``phi_rows``).
    dx_um, dy_um
        Shift of the pattern along x (columns) and y (rows), um (``mask_misalignment``).
    angle_deg
        Residual rotation after the orientation, degrees, +x towards +y (``mask_misalignment``).
    scene_to_mask_mm
        Scene-to-mask distance z that best explains the shadow's scale (magnification H/z).
    fit
        ``rows``, ``cols``: fraction of the flat field's two leading singular directions
        explained per axis (1 = exact); ``rel_rms``: relative RMS residual of the 2-D fit;
        ``turn_scan_deg``: the separability scan's turn (modulo 90°).
    """

    orientation: Orientation
    dx_um: float
    dy_um: float
    angle_deg: float
    scene_to_mask_mm: float
    fit: dict[str, float]

    @property
    def flipped(self) -> bool:
        """The mask is turned by 180° (φ and φ_rows reversed)."""
        return self.orientation == Orientation.turned(2)

    def apply(self, profile: Profile) -> Profile:
        """``profile`` with this pose: the mask vectors as mounted (:meth:`Orientation.apply`),
        ``mask_misalignment`` and ``geometry`` in ``physics``."""
        data = profile.contract_dict()
        phi_x, phi_y = self.orientation.apply(np.asarray(profile.mask.phi), np.asarray(profile.mask.rows_vector))
        data["mask"]["phi"] = [int(v) for v in phi_x]
        data["mask"]["phi_rows"] = [int(v) for v in phi_y]
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
        return {"orientation": self.orientation.to_json(), "dx_um": round(self.dx_um, 3),
                "dy_um": round(self.dy_um, 3), "angle_deg": round(self.angle_deg, 5),
                "scene_to_mask_mm": round(self.scene_to_mask_mm, 5),
                "fit": {k: round(v, 6) for k, v in self.fit.items()}}


def _score(profiles: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``(T,)``: fraction of the energy of ``target``'s columns (``n × 2``) inside the span of
    each ``n × 2`` basis ``profiles[t]`` (``(T, n, 2)``)."""
    q, _ = np.linalg.qr(profiles)
    return np.sum(np.einsum("tnk,nj->tkj", q, target) ** 2, axis=(1, 2)) / float(np.sum(target**2))


def _search(gen: DirectGenerator, phi: np.ndarray, target: np.ndarray, max_shift_um: float,
            step_um: float) -> tuple[float, float]:
    """Best shift (um) and its score; coarse grid then three 4× finer grids and a parabola."""

    axis = gen.axis

    def scores(shifts: np.ndarray, stride: int = 1) -> np.ndarray:
        index = np.arange(0, axis.n_sensor, stride)
        prof = gen.uniform_scene_profiles(phi, shifts, sensor_index=index)  # (2, T, n)
        return _score(np.transpose(prof, (1, 2, 0)), target[index])

    shifts = np.arange(-max_shift_um, max_shift_um + step_um / 2, step_um)
    vals = scores(shifts, max(1, axis.n_sensor // COARSE_SENSOR_PIXELS))
    k = int(np.argmax(vals))
    best, value = float(shifts[k]), float(vals[k])
    for _ in range(3):
        step_um /= 4.0
        local = best + step_um * np.arange(-4, 5)
        vals = scores(local)
        j = int(np.argmax(vals))
        best, value = float(local[j]), float(vals[j])
        if 0 < j < len(local) - 1:
            y0, y1, y2 = vals[j - 1], vals[j], vals[j + 1]
            den = y0 - 2 * y1 + y2
            if den < 0:
                best += 0.5 * step_um * (y0 - y2) / den
    return best, value


def _parabola_peak(x: np.ndarray, y: np.ndarray, k: int) -> float:
    """Vertex of the parabola through ``(x, y)`` at ``k − 1, k, k + 1`` (``x[k]`` at an end)."""
    if 0 < k < len(x) - 1:
        den = y[k - 1] - 2 * y[k] + y[k + 1]
        if den < 0:
            return float(x[k] + 0.5 * (x[1] - x[0]) * (y[k - 1] - y[k + 1]) / den)
    return float(x[k])


def separability_turn(y: np.ndarray, step_deg: float = TURN_STEP_DEG) -> tuple[float, float]:
    """The turn (degrees, in [−45°, 45°)) at which the image is most separable, and the share
    of its two leading singular values there.

    The image, binned (:data:`SCAN_MAX_SIDE`) and less its mean, is turned back by each trial
    angle; a central square that stays inside the sensor at every angle is scored by
    ``(σ1² + σ2²) / Σσ²``.
    """
    b = max(1, min(y.shape) // SCAN_MAX_SIDE)
    binned = y[: y.shape[0] // b * b, : y.shape[1] // b * b]
    binned = binned.reshape(y.shape[0] // b, b, y.shape[1] // b, b).mean(axis=(1, 3))
    img = binned - float(np.mean(binned))
    side = int(min(img.shape) / math.sqrt(2.0)) - 2
    r0, c0 = (img.shape[0] - side) // 2, (img.shape[1] - side) // 2

    def share(a: float) -> float:
        turned = ndimage.rotate(img, a, reshape=False, order=1, mode="constant")
        s = np.linalg.svd(turned[r0:r0 + side, c0:c0 + side], compute_uv=False) ** 2
        return float((s[0] + s[1]) / s.sum())

    angles = np.arange(-45.0, 45.0, step_deg)
    vals = np.array([share(float(a)) for a in angles])
    k = int(np.argmax(vals))
    # the scan is periodic (90°): wrap the neighbours of the ends
    ext_a = np.concatenate([[angles[-1] - 90.0], angles, [angles[0] + 90.0]])
    ext_v = np.concatenate([[vals[-1]], vals, [vals[0]]])
    best = _parabola_peak(ext_a, ext_v, k + 1)
    best = (best + 45.0) % 90.0 - 45.0
    # ndimage turns the array by a from +x towards −y (rows index y): that undoes a turn of
    # +a of the mask (+x towards +y, CONTRACTS §5)
    return best, float(vals[k])


SHIFT_NODE_UM = 0.5
"""Step of the shifts at which the flat-field model computes its one-axis profiles; the
profiles at the rows' (columns') own shifts are interpolated by local cubics (relative error
about 1e-5)."""


def _profiles_at(gen: DirectGenerator, phi: np.ndarray, shifts: np.ndarray, feature_um: float) -> np.ndarray:
    """``(2, T, n)``: :meth:`DirectGenerator.uniform_scene_profiles` at ``shifts`` (``(T,)``),
    computed on a grid of :data:`SHIFT_NODE_UM` and interpolated when that is fewer shifts."""
    lo, hi = float(shifts.min()), float(shifts.max())
    n = int(math.ceil((hi - lo) / SHIFT_NODE_UM)) + 4
    if n >= shifts.size:
        return gen.uniform_scene_profiles(phi, shifts, feature_um)
    nodes = lo - SHIFT_NODE_UM + SHIFT_NODE_UM * np.arange(n)
    table = gen.uniform_scene_profiles(phi, nodes, feature_um)  # (2, n, sensor)
    pos = np.clip((shifts - nodes[0]) / SHIFT_NODE_UM, 1.0, n - 2.000001)
    i0 = np.floor(pos).astype(np.int64)
    f = pos - i0
    # 4-point Lagrange on nodes i0 − 1 .. i0 + 2 (f in [0, 1) between i0 and i0 + 1)
    w = np.stack([-f * (f - 1) * (f - 2) / 6, (f + 1) * (f - 1) * (f - 2) / 2,
                  -(f + 1) * f * (f - 2) / 2, (f + 1) * f * (f - 1) / 6])  # (4, T)
    return sum(w[k][None, :, None] * table[:, i0 - 1 + k] for k in range(4))  # type: ignore[return-value]


class _FlatModel:
    """Open and coding halves of the flat field of a slightly turned mask (module docstring,
    step 3), for one orientation."""

    def __init__(self, profile: Profile, phi_x: np.ndarray, phi_y: np.ndarray) -> None:
        self.nominal = profile.with_physics({})
        self.phi_x, self.phi_y = phi_x, phi_y
        self.delta = profile.mask.feature_um
        rows, cols = profile.sensor.rows, profile.sensor.cols
        p = profile.sensor.pixel_pitch_um
        self.y_um = (np.arange(rows) - (rows - 1) / 2) * p
        self.x_um = (np.arange(cols) - (cols - 1) / 2) * p
        self._gens: dict[float, tuple[DirectGenerator, DirectGenerator]] = {}
        yy, xx = np.meshgrid(np.linspace(-1, 1, rows), np.linspace(-1, 1, cols), indexing="ij")
        self.envelope = np.stack([xx**i * yy**j for i in range(ENVELOPE_DEGREE + 1)
                                  for j in range(ENVELOPE_DEGREE + 1 - i)])

    def generators(self, z_mm: float) -> tuple[DirectGenerator, DirectGenerator]:
        if z_mm not in self._gens:
            self._gens = {z_mm: (DirectGenerator(replace(AxisGeometry.cols_of(self.nominal), z_mm=z_mm)),
                                 DirectGenerator(replace(AxisGeometry.rows_of(self.nominal), z_mm=z_mm)))}
        return self._gens[z_mm]

    def halves(self, angle_deg: float, dx_um: float, dy_um: float, z_mm: float) -> np.ndarray:
        """``(2, R, S)``: the open and coding halves of the flat field."""
        gen_x, gen_y = self.generators(z_mm)
        alpha = z_mm / (z_mm + self.nominal.geometry.mask_to_sensor_mm)
        a = math.radians(angle_deg)
        t, feature = math.tan(a), self.delta / math.cos(a)
        sx = dx_um - t * (alpha * self.y_um - dy_um)  # per row
        sy = dy_um + t * (alpha * self.x_um - dx_um)  # per column
        px = _profiles_at(gen_x, self.phi_x, sx, feature)  # (2, R, S)
        py = _profiles_at(gen_y, self.phi_y, sy, feature)  # (2, S, R)
        return px * np.transpose(py, (0, 2, 1))

    def residual(self, y: np.ndarray, angle_deg: float, dx_um: float, dy_um: float, z_mm: float
                 ) -> np.ndarray:
        """Residual image (flattened) after the best smooth gains of the two halves."""
        h = self.halves(angle_deg, dx_um, dy_um, z_mm)
        basis = (h[:, None] * self.envelope[None]).reshape(-1, y.size)
        gram = basis @ basis.T
        norm = np.sqrt(np.diag(gram))  # normal equations, equilibrated (12 unknowns)
        coef = np.linalg.solve(gram / np.outer(norm, norm), (basis @ y.ravel()) / norm) / norm
        return np.asarray(y.ravel() - coef @ basis)


def estimate_pose(flat_dn: np.ndarray, profile: Profile, *, z_range: float = 0.06, z_steps: int = 7,
                  max_residual_deg: float = MAX_RESIDUAL_DEG) -> PoseEstimate:
    """Estimate the mask's pose from a flat field.

    Parameters
    ----------
    flat_dn
        ``R × S`` or ``R × S × C`` signal of a uniform scene, DN above black.
    profile
        The device profile (its nominal geometry and design φ, φ_rows; its ``physics`` is ignored).
    z_range, z_steps
        Scene-to-mask distances tried before the joint fit: nominal × (1 ± ``z_range``) in
        ``z_steps`` steps.
    max_residual_deg
        Largest accepted turn away from the nearest of the 8 mountings, degrees.

    Raises
    ------
    CalibrationError
        Wrong shape or no signal; or the mask is turned too far from every mounting for a
        separable model (the message gives the angle found).
    """
    y = np.asarray(flat_dn, np.float64)
    if y.ndim == 3:
        y = y.mean(axis=2)
    if y.shape != (profile.sensor.rows, profile.sensor.cols):
        raise CalibrationError(f"flat field is {y.shape[0]}×{y.shape[1]} but profile {profile.name!r} has a "
                               f"{profile.sensor.rows}×{profile.sensor.cols} sensor")
    if not np.all(np.isfinite(y)) or float(np.mean(y)) <= 0:
        raise CalibrationError("the flat field has no positive signal above black: light the sensor uniformly")
    turn, turn_share = separability_turn(y)
    if abs(turn) > max_residual_deg:
        raise CalibrationError(
            f"the mask's shadow is turned by {turn:+.1f}° from the nearest quarter turn (the flat field "
            f"is most separable there, {turn_share:.3f} of its energy in two singular values): a "
            f"separable model (direct generation, the T2S decoders) holds only within "
            f"±{max_residual_deg:g}° of one of the 8 mountings of a square mask; remount the mask "
            "closer to the sensor's axes")
    nominal = profile.with_physics({})
    u, _, vt = np.linalg.svd(y, full_matrices=False)
    rows_target, cols_target = u[:, :2], vt[:2].T
    phi = np.asarray(profile.mask.phi, float)
    phi_rows = np.asarray(profile.mask.rows_vector, float)
    delta = profile.mask.feature_um
    max_shift = profile.mask.K * delta / 4.0
    z0 = profile.geometry.scene_to_mask_mm

    def axis_fits(z: float, vec_x: np.ndarray, vec_y: np.ndarray) -> tuple[float, float, float, float]:
        gen_x = DirectGenerator(replace(AxisGeometry.cols_of(nominal), z_mm=z))
        gen_y = DirectGenerator(replace(AxisGeometry.rows_of(nominal), z_mm=z))
        dx, s_c = _search(gen_x, vec_x, cols_target, max_shift, delta / 2)
        dy, s_r = _search(gen_y, vec_y, rows_target, max_shift, delta / 2)
        return dx, dy, s_r, s_c

    # orientation at the nominal distance (each distinct axis vector searched once)
    gen_x0 = DirectGenerator(AxisGeometry.cols_of(nominal))
    gen_y0 = DirectGenerator(AxisGeometry.rows_of(nominal))
    cache: dict[tuple[str, bytes], float] = {}

    def axis_score(which: str, vec: np.ndarray) -> float:
        key = (which, vec.tobytes())
        if key not in cache:
            gen, target = (gen_x0, cols_target) if which == "x" else (gen_y0, rows_target)
            cache[key] = _search(gen, vec, target, max_shift, delta / 2)[1]
        return cache[key]

    scores = [axis_score("x", o.apply(phi, phi_rows)[0]) + axis_score("y", o.apply(phi, phi_rows)[1])
              for o in ORIENTATIONS]
    orientation = ORIENTATIONS[int(np.argmax(scores))]  # the first of equals (same mounted mask)
    phi_x, phi_y = orientation.apply(phi, phi_rows)
    zs = z0 * np.linspace(1 - z_range, 1 + z_range, z_steps)
    trials = [axis_fits(float(z), phi_x, phi_y) for z in zs]
    totals = np.array([t[2] + t[3] for t in trials])
    z = _parabola_peak(zs, totals, int(np.argmax(totals)))
    dx, dy, s_r, s_c = axis_fits(z, phi_x, phi_y)

    # joint least squares of angle, offset and z on the whole image
    model = _FlatModel(profile, phi_x, phi_y)
    scale = float(np.sqrt(np.mean(y**2)))
    unit = np.array([0.01, 0.1, 0.1, 0.001])  # deg, um, um, mm per unit of the solver's variables
    x0 = np.array([turn, dx, dy, z])

    def fun(v: np.ndarray) -> np.ndarray:
        a, sx_, sy_, zz = x0 + v * unit
        return model.residual(y, float(a), float(sx_), float(sy_), float(zz)) / scale

    sol = optimize.least_squares(fun, np.zeros(4), diff_step=1e-3, method="lm", xtol=1e-10)
    angle, dx, dy, z = (float(v) for v in x0 + sol.x * unit)
    rel_rms = float(np.sqrt(np.mean(sol.fun**2)))
    return PoseEstimate(orientation, dx, dy, angle, z,
                        {"rows": s_r, "cols": s_c, "rel_rms": rel_rms, "turn_scan_deg": turn})
