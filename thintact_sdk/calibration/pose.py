"""The mask's pose from one flat-field capture: orientation (any quarter turn, mirror images),
residual rotation, offset and the shadow's scale, with how sure the estimate is.

A uniformly lit scene gives ``Y = (Po·1)(Qo·1)ᵀ + (Pc·1)(Qc·1)ᵀ``: along each axis the image
lies in the span of the open profile ``Po·1`` and the coding profile ``Pc·1``, which is the
known φ seen through the geometry (direct generation, :mod:`thintact_sdk.reconstruction.direct_generation`).

0. **Working size.** A frame larger than :data:`WORK_MAX_SIDE` along its longer side is binned
   ``b × b`` (a centred crop to a multiple of ``b``) while the shadow keeps at least
   :data:`MIN_PX_PER_CELL` pixels per mask cell; the pose is fitted on the binned sensor
   (pitch ``b·p``) and mapped back (offsets in um and z are physical; a fitted pitch is
   divided by ``b``; the crop's half-pixel centring is added to the offsets).
1. **Turn.** The flat field of a mask turned by ``a`` is separable (rank 2) only when read
   along the mask's own axes: the image turned back by each trial angle in [−45°, 45°) is scored
   by the share of its two leading singular values. The best angle modulo 90° is the residual
   turn of every one of the 8 mountings; beyond :data:`MAX_RESIDUAL_DEG` no separable model
   holds and the estimate stops there.
2. **Scale.** The shadow's cell on the sensor is ``δ·H/(z·p)`` pixels. With ``unknown`` set to
   ``"z"`` or ``"pitch"`` that one is scanned over the user's bounds on a grid uniform in the
   shadow's scale (steps of :data:`SCALE_STEP_CELLS` of a cell at the edge of the sensor),
   every candidate axis vector scored at every scale; each mounting keeps its best scale.
3. **Hypotheses.** Each of the 8 mountings picks one of 4 vectors per axis (φ or φ_rows,
   forward or reversed); its score per axis is the share of the image's two leading singular
   directions that the pose's two profiles span at the best shift. The scores are standardised
   by the same search run with :data:`NULL_SAMPLES` random ±1 vectors of the same length per
   axis (their mean and spread: what a pattern that is *not* on the mask scores on this
   image). The best mounting must reach :data:`FLOOR_SIGMA` random-mask spreads above the
   random mean on both axes, and beat the runner-up (the best mounting that gives a different
   mask) by :data:`MARGIN_SIGMA`; otherwise the estimate is *unsure* and says why.
4. **Residual rotation, offset, scale.** A slightly turned mask reads the pattern at
   ``p_x = cos θ·(m_x − dx) + sin θ·(m_y − dy)``: along each sensor row the column profile is
   the one-axis profile with cells ``δ/cos θ`` shifted by ``dx − tan θ·(m_y − dy)``, ``m_y`` the
   row's mask-plane coordinate, and likewise for the columns. Angle, offset and the unknown
   (z or p) are fitted jointly by least squares on the whole 2-D image against this model, the
   gains of its open and coding halves (a low-order polynomial each) solved linearly. The
   unknown's uncertainty is the least-squares standard error, widened by the residual's
   correlation length (the pixels' residuals are not independent).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from scipy import ndimage, optimize

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.reconstruction.direct_generation import AxisGeometry, DirectGenerator
from thintact_sdk.reconstruction.mask_orientation import ORIENTATIONS, Orientation

Unknown = Literal["z", "pitch", "none"]
Progress = Callable[[str], None]

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

WORK_MAX_SIDE = 512
"""Frames longer than this (pixels, longer side) are binned to a working size first."""

MIN_PX_PER_CELL = 3.0
"""The working binning keeps at least this many pixels per shadow cell (at the smallest shadow
the scale bounds allow): a cell edge must stay resolved for the shift search."""

SCALE_STEP_CELLS = 0.5
"""Step of the scale scan: the shadow's cells at the edge of the sensor move by this fraction
of a cell from one trial scale to the next (the score's peak in scale is about one cell wide
there)."""

NULL_SAMPLES = 24
"""Random ±1 vectors per axis whose scores give the random-mask mean and spread."""

FLOOR_SIGMA = 6.0
"""The best mounting's score on each axis must exceed the random-mask mean by this many
random-mask spreads (a one-sided 6σ event of the null is far rarer than the few hundred
vector/shift/scale trials the search makes), else the pattern is not found: unsure."""

MARGIN_SIGMA = 3.0
"""The best mounting must beat the runner-up by this many random-mask spreads (summed over
the axes): a wrong vector of a runner-up scores like a random one on its wrong axis, so a gap
below 3 spreads is within what the null's own fluctuation gives; then the estimate is unsure."""

DEFAULT_Z_BOUNDS = 0.10
"""Default bounds of an unknown z: nominal × (1 ± this)."""

DEFAULT_PITCH_BOUNDS = (0.8, 1.25)
"""Default bounds of an unknown pitch, as factors of the profile's pitch."""


@dataclass
class MountingScore:
    """One mounting hypothesis: its per-axis scores (raw: share of the two leading singular
    directions spanned, 1 = exact; ``sigma``: random-mask spreads above the random mean), the
    scale value (z in mm or pitch in um, whichever is unknown) where it scored best."""

    orientation: Orientation
    score_x: float
    score_y: float
    sigma_x: float
    sigma_y: float
    scale_value: float

    @property
    def sigma(self) -> float:
        return self.sigma_x + self.sigma_y

    def to_json(self) -> dict[str, Any]:
        return {"mounting": self.orientation.name, "score_x": round(self.score_x, 6),
                "score_y": round(self.score_y, 6), "sigma_x": round(self.sigma_x, 2),
                "sigma_y": round(self.sigma_y, 2), "sigma": round(self.sigma, 2),
                "scale_value": round(self.scale_value, 6)}


@dataclass
class PoseEstimate:
    """Where the mask is, and how sure that is.

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
        Scene-to-mask distance z (fitted when ``unknown == "z"``, else the profile's).
    pixel_pitch_um
        Sensor pixel pitch p of the full-size frame (fitted when ``unknown == "pitch"``).
    fit
        ``rows``, ``cols``: raw axis scores of the chosen mounting; ``rel_rms``: relative RMS
        residual of the 2-D fit; ``turn_scan_deg``: the separability scan's turn (modulo 90°);
        ``binning``: the working binning; ``shadow_px_per_cell``: the fitted shadow cell on
        the full-size sensor, pixels; ``null_mean_x/y``, ``null_std_x/y``: the random masks'
        score mean and spread.
    unknown
        Which of z / pitch was fitted (``"none"``: neither).
    scale_sigma
        1σ uncertainty of the fitted unknown (mm for z, um for pitch; 0 when none).
    hypotheses
        All 8 mountings, best first.
    runner_up
        The best mounting that gives a different mask than the chosen one (None when the
        design makes all 8 the same mask).
    confident
        False when the floor or the margin is not met, or the fitted unknown left its bounds.
    problems
        Sentences saying why the estimate is unsure (empty when confident).
    ambiguities
        Ambiguities the design makes unavoidable, each with what would resolve it.
    """

    orientation: Orientation
    dx_um: float
    dy_um: float
    angle_deg: float
    scene_to_mask_mm: float
    fit: dict[str, float]
    pixel_pitch_um: float = 0.0
    unknown: str = "z"
    scale_sigma: float = 0.0
    hypotheses: list[MountingScore] = field(default_factory=list)
    runner_up: MountingScore | None = None
    confident: bool = True
    problems: list[str] = field(default_factory=list)
    ambiguities: list[str] = field(default_factory=list)
    bounds: tuple[float, float] | None = None

    @property
    def flipped(self) -> bool:
        """The mask is turned by 180° (φ and φ_rows reversed)."""
        return self.orientation == Orientation.turned(2)

    @property
    def margin_sigma(self) -> float:
        """Best minus runner-up, random-mask spreads (inf when there is no runner-up)."""
        if not self.hypotheses or self.runner_up is None:
            return math.inf
        return self.hypotheses[0].sigma - self.runner_up.sigma

    def apply(self, profile: Profile) -> Profile:
        """``profile`` with this pose: the mask vectors as mounted (:meth:`Orientation.apply`),
        ``mask_misalignment`` and ``geometry`` in ``physics``; a fitted pitch replaces
        ``sensor.pixel_pitch_um``."""
        data = profile.contract_dict()
        phi_x, phi_y = self.orientation.apply(np.asarray(profile.mask.phi), np.asarray(profile.mask.rows_vector))
        data["mask"]["phi"] = [int(v) for v in phi_x]
        data["mask"]["phi_rows"] = [int(v) for v in phi_y]
        if self.unknown == "pitch" and self.pixel_pitch_um > 0:
            data["sensor"]["pixel_pitch_um"] = round(self.pixel_pitch_um, 6)
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
                "pixel_pitch_um": round(self.pixel_pitch_um, 6), "unknown": self.unknown,
                "scale_sigma": round(self.scale_sigma, 6),
                "bounds": list(self.bounds) if self.bounds else None,
                "fit": {k: round(v, 6) for k, v in self.fit.items()},
                "confident": self.confident, "margin_sigma": round(self.margin_sigma, 3)
                if math.isfinite(self.margin_sigma) else None,
                "floor_sigma": FLOOR_SIGMA, "required_margin_sigma": MARGIN_SIGMA,
                "runner_up": self.runner_up.to_json() if self.runner_up else None,
                "hypotheses": [h.to_json() for h in self.hypotheses],
                "problems": list(self.problems), "ambiguities": list(self.ambiguities)}


def _score(profiles: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``(T,)``: of the energy of ``target``'s columns (``n × 2``) outside the span of each open
    profile ``profiles[t, :, 0]``, the fraction the coding profile ``profiles[t, :, 1]`` adds
    (``(T, n, 2)``; 1 = exact, about 0 for a pattern unrelated to the image). The open profile
    alone explains most of a flat field (its mean brightness), whatever the mask, so the score
    is taken on what it leaves."""
    q, _ = np.linalg.qr(profiles)
    proj = np.einsum("tnk,nj->tkj", q, target) ** 2  # (T, 2, 2)
    rest = float(np.sum(target**2)) - np.sum(proj[:, 0], axis=1)
    return np.sum(proj[:, 1], axis=1) / np.maximum(rest, 1e-300)


def _log_gain(score: np.ndarray) -> np.ndarray:
    """``−log(1 − score)``: the log ratio of the unexplained energy without and with the coding
    profile (a Gaussian log-likelihood ratio per degree of freedom); the scale on which
    hypotheses are compared with the random masks."""
    return -np.log(np.clip(1.0 - np.asarray(score, np.float64), 1e-12, None))


def _search(gen: DirectGenerator, phi: np.ndarray, target: np.ndarray, max_shift_um: float,
            step_um: float, levels: int = 3) -> tuple[float, float]:
    """Best shift (um) and its score; coarse grid then ``levels`` 4× finer grids and a parabola."""

    axis = gen.axis

    def scores(shifts: np.ndarray, stride: int = 1) -> np.ndarray:
        index = np.arange(0, axis.n_sensor, stride)
        prof = gen.uniform_scene_profiles(phi, shifts, sensor_index=index)  # (2, T, n)
        return _score(np.transpose(prof, (1, 2, 0)), target[index])

    shifts = np.arange(-max_shift_um, max_shift_um + step_um / 2, step_um)
    vals = scores(shifts, max(1, axis.n_sensor // COARSE_SENSOR_PIXELS))
    k = int(np.argmax(vals))
    best, value = float(shifts[k]), float(vals[k])
    for _ in range(levels):
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
            x0, x1, x2 = x[k - 1], x[k], x[k + 1]
            if abs((x2 - x1) - (x1 - x0)) < 1e-9 * abs(x2 - x0):
                return float(x1 + 0.5 * (x1 - x0) * (y[k - 1] - y[k + 1]) / den)
            # unequal steps: vertex of the interpolating parabola
            a = ((y[k + 1] - y[k]) / (x2 - x1) - (y[k] - y[k - 1]) / (x1 - x0)) / (x2 - x0)
            b = (y[k] - y[k - 1]) / (x1 - x0) - a * (x1 + x0)
            if a < 0:
                return float(min(max(-b / (2 * a), x0), x2))
    return float(x[k])


def separability_turn(y: np.ndarray, step_deg: float = TURN_STEP_DEG) -> tuple[float, float]:
    """The turn (degrees, in [−45°, 45°)) at which the image is most separable, and the share
    of its two leading singular values there.

    The image, binned (:data:`SCAN_MAX_SIDE`) and less its mean, is turned back by each trial
    angle; a central square that stays inside the sensor at every angle is scored by
    ``(σ1² + σ2²) / Σσ²``.
    """
    b = max(1, min(y.shape) // SCAN_MAX_SIDE)
    binned = bin_image(y, b)[0]
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


def bin_image(y: np.ndarray, b: int) -> tuple[np.ndarray, tuple[float, float]]:
    """``y`` (``R × S``) binned ``b × b`` after a centred crop to a multiple of ``b``, and the
    crop's centre relative to the frame's centre, ``(rows, cols)`` in full-size pixels
    (0 or −0.5 each)."""
    rows, cols = y.shape
    rr, cc = rows // b * b, cols // b * b
    r0, c0 = (rows - rr) // 2, (cols - cc) // 2
    cut = y[r0:r0 + rr, c0:c0 + cc]
    out = cut.reshape(rr // b, b, cc // b, b).mean(axis=(1, 3)) if b > 1 else cut
    return out, (r0 + (rr - 1) / 2 - (rows - 1) / 2, c0 + (cc - 1) / 2 - (cols - 1) / 2)


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


def _geometry(profile: Profile, z_mm: float, pitch_um: float) -> tuple[AxisGeometry, AxisGeometry]:
    """The column (x) and row (y) axes of ``profile`` (its physics ignored) at ``z``, ``p``."""
    cols, rows = AxisGeometry.cols_of(profile), AxisGeometry.rows_of(profile)
    return (replace(cols, z_mm=z_mm, sensor_pitch_um=pitch_um, mask_shift_um=0.0, turn_blur_um=0.0),
            replace(rows, z_mm=z_mm, sensor_pitch_um=pitch_um, mask_shift_um=0.0, turn_blur_um=0.0))


class _FlatModel:
    """Open and coding halves of the flat field of a slightly turned mask (module docstring,
    step 4), for one orientation, on the working sensor."""

    def __init__(self, profile: Profile, phi_x: np.ndarray, phi_y: np.ndarray) -> None:
        self.nominal = profile.with_physics({})
        self.phi_x, self.phi_y = phi_x, phi_y
        self.delta = profile.mask.feature_um
        self.rows, self.cols = profile.sensor.rows, profile.sensor.cols
        self._gens: dict[tuple[float, float], tuple[DirectGenerator, DirectGenerator]] = {}
        yy, xx = np.meshgrid(np.linspace(-1, 1, self.rows), np.linspace(-1, 1, self.cols), indexing="ij")
        self.envelope = np.stack([xx**i * yy**j for i in range(ENVELOPE_DEGREE + 1)
                                  for j in range(ENVELOPE_DEGREE + 1 - i)])

    def generators(self, z_mm: float, pitch_um: float) -> tuple[DirectGenerator, DirectGenerator]:
        key = (z_mm, pitch_um)
        if key not in self._gens:
            gx, gy = _geometry(self.nominal, z_mm, pitch_um)
            self._gens = {key: (DirectGenerator(gx), DirectGenerator(gy))}
        return self._gens[key]

    def halves(self, angle_deg: float, dx_um: float, dy_um: float, z_mm: float, pitch_um: float) -> np.ndarray:
        """``(2, R, S)``: the open and coding halves of the flat field."""
        gen_x, gen_y = self.generators(z_mm, pitch_um)
        y_um = (np.arange(self.rows) - (self.rows - 1) / 2) * pitch_um
        x_um = (np.arange(self.cols) - (self.cols - 1) / 2) * pitch_um
        alpha = z_mm / (z_mm + self.nominal.geometry.mask_to_sensor_mm)
        a = math.radians(angle_deg)
        t, feature = math.tan(a), self.delta / math.cos(a)
        sx = dx_um - t * (alpha * y_um - dy_um)  # per row
        sy = dy_um + t * (alpha * x_um - dx_um)  # per column
        px = _profiles_at(gen_x, self.phi_x, sx, feature)  # (2, R, S)
        py = _profiles_at(gen_y, self.phi_y, sy, feature)  # (2, S, R)
        return px * np.transpose(py, (0, 2, 1))

    def residual(self, y: np.ndarray, angle_deg: float, dx_um: float, dy_um: float, z_mm: float,
                 pitch_um: float) -> np.ndarray:
        """Residual image (flattened) after the best smooth gains of the two halves."""
        h = self.halves(angle_deg, dx_um, dy_um, z_mm, pitch_um)
        basis = (h[:, None] * self.envelope[None]).reshape(-1, y.size)
        gram = basis @ basis.T
        norm = np.sqrt(np.diag(gram))  # normal equations, equilibrated
        coef = np.linalg.solve(gram / np.outer(norm, norm), (basis @ y.ravel()) / norm) / norm
        return np.asarray(y.ravel() - coef @ basis)


def _correlation_length(res: np.ndarray) -> float:
    """Pixels over which the residual image stays correlated: the product of the lags (rows,
    columns) where its mean autocorrelation first drops below 1/e, at least 1."""
    lengths = []
    for img in (res, res.T):
        z = img - img.mean(axis=1, keepdims=True)
        var = float(np.mean(z * z))
        lag = 1
        while lag < z.shape[1] // 2 and var > 0:
            if float(np.mean(z[:, lag:] * z[:, :-lag])) / var < math.exp(-1):
                break
            lag += 1
        lengths.append(lag)
    return float(max(1, lengths[0] * lengths[1]))


def working_binning(profile: Profile, unknown: str, bounds: tuple[float, float] | None,
                    work_max_side: int = WORK_MAX_SIDE) -> int:
    """The binning ``b`` for the pose: the longer side at most ``work_max_side`` pixels, unless
    that leaves the shadow fewer than :data:`MIN_PX_PER_CELL` pixels per cell at the smallest
    shadow the bounds allow."""
    g = profile.geometry
    z, p = g.scene_to_mask_mm, profile.sensor.pixel_pitch_um
    if unknown == "z" and bounds:
        z = bounds[1]
    elif unknown == "pitch" and bounds:
        p = bounds[1]
    cell_px = profile.mask.feature_um * (z + g.mask_to_sensor_mm) / (z * p)
    b = math.ceil(max(profile.sensor.rows, profile.sensor.cols) / work_max_side)
    return int(max(1, min(b, math.floor(cell_px / MIN_PX_PER_CELL))))


def _design_ambiguities(phi: np.ndarray, phi_rows: np.ndarray) -> list[str]:
    """Ambiguities the design itself makes unavoidable, with what resolves them."""
    out = []
    if np.array_equal(phi, phi_rows) or np.array_equal(phi, phi_rows[::-1]):
        out.append("rows and columns share one sequence (phi_rows is phi or phi reversed): a mounting "
                   "and its transpose give the same mask, so the 8 mountings are 4 distinct masks, and a "
                   "turn by 90° and one by 180° differ only by one axis read reversed, which only that "
                   "axis's fit tells apart; a flat field cannot do better. Resolve it with an asymmetric "
                   "target (a scene or a press at a known corner, reconstructed with both poses), a known "
                   "edge of the mask seen on the sensor, or a second flat field after a known quarter turn")
    for name, v in (("phi", phi), ("phi_rows", phi_rows)):
        if np.array_equal(v, v[::-1]):
            out.append(f"{name} is a palindrome: a mirror image along its axis gives the same mask "
                       "(harmless: the mounted mask is identical)")
    return out


def estimate_pose(flat_dn: np.ndarray, profile: Profile, *, unknown: Unknown = "z",
                  bounds: tuple[float, float] | None = None,
                  max_residual_deg: float = MAX_RESIDUAL_DEG, work_max_side: int = WORK_MAX_SIDE,
                  null_samples: int = NULL_SAMPLES, seed: int = 0,
                  progress: Progress | None = None) -> PoseEstimate:
    """Estimate the mask's pose from a flat field, with its runner-up and confidence.

    Parameters
    ----------
    flat_dn
        ``R × S`` or ``R × S × C`` signal of a uniform scene, DN above black.
    profile
        The device profile (its nominal geometry and design φ, φ_rows; its ``physics`` is ignored).
    unknown
        ``"z"``: fit the scene-to-mask distance (mm); ``"pitch"``: fit the sensor pixel pitch
        (um, of the full-size frame) at the profile's z; ``"none"``: both as the profile says.
    bounds
        ``(low, high)`` of the unknown (mm or um). Default: z × (1 ± :data:`DEFAULT_Z_BOUNDS`),
        p × :data:`DEFAULT_PITCH_BOUNDS`. The scan stays inside; the final fit may leave
        them, and then the estimate is unsure and says so.
    max_residual_deg
        Largest accepted turn away from the nearest of the 8 mountings, degrees.
    work_max_side
        Working size (:func:`working_binning`).
    null_samples, seed
        Random ±1 vectors per axis for the random-mask scores, and their seed.
    progress
        Called with one line per step (long steps: several).

    Raises
    ------
    CalibrationError
        Wrong shape or no signal; bad bounds; or the mask is turned too far from every mounting
        for a separable model (the message gives the angle found).
    """
    say = progress or (lambda _msg: None)
    y_full = np.asarray(flat_dn, np.float64)
    if y_full.ndim == 3:
        y_full = y_full.mean(axis=2)
    if y_full.shape != (profile.sensor.rows, profile.sensor.cols):
        raise CalibrationError(f"flat field is {y_full.shape[0]}×{y_full.shape[1]} but profile {profile.name!r} "
                               f"has a {profile.sensor.rows}×{profile.sensor.cols} sensor")
    if not np.all(np.isfinite(y_full)) or float(np.mean(y_full)) <= 0:
        raise CalibrationError("the flat field has no positive signal above black: light the sensor uniformly")
    if unknown not in ("z", "pitch", "none"):
        raise CalibrationError(f"unknown must be 'z', 'pitch' or 'none', got {unknown!r}")
    z0, p0 = profile.geometry.scene_to_mask_mm, profile.sensor.pixel_pitch_um
    d_mm = profile.geometry.mask_to_sensor_mm
    if unknown == "z":
        lo, hi = bounds or (z0 * (1 - DEFAULT_Z_BOUNDS), z0 * (1 + DEFAULT_Z_BOUNDS))
    elif unknown == "pitch":
        lo, hi = bounds or (p0 * DEFAULT_PITCH_BOUNDS[0], p0 * DEFAULT_PITCH_BOUNDS[1])
    else:
        lo = hi = z0
    if not (0 < lo <= hi and math.isfinite(hi)):
        raise CalibrationError(f"bounds of the unknown {unknown}: need 0 < low <= high, got ({lo}, {hi})")

    b = working_binning(profile, unknown, (lo, hi) if unknown != "none" else None, work_max_side)
    y, (crop_r, crop_c) = bin_image(y_full, b)
    work = profile.with_physics({})
    work = work.model_copy(update={"sensor": work.sensor.model_copy(update={
        "rows": y.shape[0], "cols": y.shape[1], "pixel_pitch_um": p0 * b})})
    say(f"working size {y.shape[0]}×{y.shape[1]} (binned {b}×{b} from {y_full.shape[0]}×{y_full.shape[1]})")

    say("turn: separability scan over [-45°, 45°)")
    turn, turn_share = separability_turn(y)
    if abs(turn) > max_residual_deg:
        raise CalibrationError(
            f"the mask's shadow is turned by {turn:+.1f}° from the nearest quarter turn (the flat field "
            f"is most separable there, {turn_share:.3f} of its energy in two singular values): a "
            f"separable model (direct generation, the T2S decoders) holds only within "
            f"±{max_residual_deg:g}° of one of the 8 mountings of a square mask; remount the mask "
            "closer to the sensor's axes")
    u, _, vt = np.linalg.svd(y - 0.0, full_matrices=False)
    rows_target, cols_target = u[:, :2], vt[:2].T
    phi = np.asarray(profile.mask.phi, float)
    phi_rows = np.asarray(profile.mask.rows_vector, float)
    delta, k_cells = profile.mask.feature_um, profile.mask.K

    def z_p(value: float) -> tuple[float, float]:
        """(z mm, working pitch um) for a value of the unknown."""
        if unknown == "z":
            return value, p0 * b
        if unknown == "pitch":
            return z0, value * b
        return z0, p0 * b

    # the visible part of the mask and how far the search may shift the pattern
    alpha0 = z0 / (z0 + d_mm)
    visible_half = 0.5 * max(y.shape) * p0 * b * alpha0
    max_shift = max(k_cells * delta / 4.0, k_cells * delta / 2.0 - visible_half)
    n_cells = 2 * visible_half / delta

    # scale grid, uniform in log of the shadow's scale H/(z·p)
    if unknown == "none":
        values = np.array([z0])
    else:
        def shadow(v: float) -> float:
            zz, pp = z_p(v)
            return (zz + d_mm) / (zz * pp)

        s_lo, s_hi = sorted((shadow(lo), shadow(hi)))
        step = SCALE_STEP_CELLS / max(n_cells, 1.0)
        n_steps = max(3, int(math.ceil(math.log(s_hi / s_lo) / step)) + 1)
        scales = np.exp(np.linspace(math.log(s_lo), math.log(s_hi), n_steps))
        if unknown == "z":
            values = d_mm / (scales * p0 * b - 1.0)  # σ·p = 1 + d/z
        else:
            values = (z0 + d_mm) / (z0 * scales) / b
        values = np.sort(values)

    candidates = {"x": [phi, phi[::-1], phi_rows, phi_rows[::-1]],
                  "y": [phi, phi[::-1], phi_rows, phi_rows[::-1]]}

    def key_of(vec: np.ndarray) -> bytes:
        return np.asarray(vec, np.int8).tobytes()

    gens: dict[float, tuple[DirectGenerator, DirectGenerator]] = {}

    def gens_at(v: float) -> tuple[DirectGenerator, DirectGenerator]:
        if v not in gens:
            gx, gy = _geometry(work, *z_p(v))
            gens[v] = (DirectGenerator(gx), DirectGenerator(gy))
        return gens[v]

    # scan: every distinct candidate per axis at every scale (coarse grid and one refinement)
    scan: dict[tuple[str, bytes], np.ndarray] = {}
    for i, v in enumerate(values):
        if len(values) > 1:
            say(f"scale scan {i + 1}/{len(values)}: {unknown} = {v:.4f} {'mm' if unknown == 'z' else 'um'}")
        gx, gy = gens_at(float(v))
        for axis, gen, target in (("x", gx, cols_target), ("y", gy, rows_target)):
            for vec in candidates[axis]:
                key = (axis, key_of(vec))
                if key not in scan:
                    scan[key] = np.zeros(len(values))
                elif scan[key][i] != 0:
                    continue
                scan[key][i] = _search(gen, vec, target, max_shift, delta / 2,
                                       levels=1 if len(values) > 1 else 3)[1]

    # each mounting at its own best scale, then scored in full there
    full: dict[tuple[str, bytes, float], tuple[float, float]] = {}

    def full_score(axis: str, vec: np.ndarray, v: float) -> tuple[float, float]:
        key = (axis, key_of(vec), v)
        if key not in full:
            gx, gy = gens_at(v)
            gen, target = (gx, cols_target) if axis == "x" else (gy, rows_target)
            full[key] = _search(gen, vec, target, max_shift, delta / 2)
        return full[key]

    say("scoring the 8 mountings")
    best_value: dict[Orientation, float] = {}
    for o in ORIENTATIONS:
        vx, vy = o.apply(phi, phi_rows)
        total = scan[("x", key_of(vx))] + scan[("y", key_of(vy))]
        k = int(np.argmax(total))
        v = values[k] if len(values) < 3 else _parabola_peak(values, total, k)
        best_value[o] = float(v)
    raw = {}
    for o in ORIENTATIONS:
        vx, vy = o.apply(phi, phi_rows)
        raw[o] = (full_score("x", vx, best_value[o])[1], full_score("y", vy, best_value[o])[1])
    lead = max(ORIENTATIONS, key=lambda o: raw[o][0] + raw[o][1])

    say(f"random-mask scores: {null_samples} random vectors per axis")
    rng = np.random.default_rng(seed)
    gx, gy = gens_at(best_value[lead])
    null = {"x": [], "y": []}  # type: dict[str, list[float]]
    for _ in range(null_samples):
        for axis, gen, target in (("x", gx, cols_target), ("y", gy, rows_target)):
            vec = rng.choice([-1.0, 1.0], k_cells)
            null[axis].append(_search(gen, vec, target, max_shift, delta / 2, levels=1)[1])
    mu = {a: float(np.mean(_log_gain(np.array(null[a])))) for a in null}
    sd = {a: max(float(np.std(_log_gain(np.array(null[a])), ddof=1)), 1e-12) for a in null}

    def sig(axis: str, s: float) -> float:
        return float((_log_gain(np.array(s)) - mu[axis]) / sd[axis])

    hyps = [MountingScore(o, raw[o][0], raw[o][1], sig("x", raw[o][0]), sig("y", raw[o][1]), best_value[o])
            for o in ORIENTATIONS]
    hyps.sort(key=lambda h: -h.sigma)  # stable: the first of equals (same mounted mask) stays first
    best = hyps[0]
    orientation = best.orientation
    phi_x, phi_y = orientation.apply(phi, phi_rows)

    def same_mask(o: Orientation) -> bool:
        ox, oy = o.apply(phi, phi_rows)
        return bool(np.array_equal(ox, phi_x) and np.array_equal(oy, phi_y))

    runner = next((h for h in hyps[1:] if not same_mask(h.orientation)), None)

    # joint least squares of angle, offset and the unknown on the whole image
    say("joint fit of turn, offset and scale on the whole image")
    v0 = best.scale_value
    zz0, pp0 = z_p(v0)
    gx0, gy0 = gens_at(v0)
    dx = _search(gx0, phi_x, cols_target, max_shift, delta / 2)[0]
    dy = _search(gy0, phi_y, rows_target, max_shift, delta / 2)[0]
    model = _FlatModel(work, phi_x, phi_y)
    scale = float(np.sqrt(np.mean(y**2)))
    free = unknown != "none"
    unit_v = 0.001 if unknown == "z" else 0.0001 * p0
    unit = np.array([0.01, 0.1, 0.1] + ([unit_v] if free else []))
    x0 = np.array([turn, dx, dy] + ([v0] if free else []))

    def unpack(v: np.ndarray) -> tuple[float, float, float, float, float]:
        vals = x0 + v * unit
        zz, pp = z_p(float(vals[3])) if free else (zz0, pp0)
        return float(vals[0]), float(vals[1]), float(vals[2]), zz, pp

    def fun(v: np.ndarray) -> np.ndarray:
        return model.residual(y, *unpack(v)) / scale

    sol = optimize.least_squares(fun, np.zeros(len(x0)), diff_step=1e-3, method="lm", xtol=1e-10)
    angle, dx, dy, z, p_work = unpack(sol.x)
    rel_rms = float(np.sqrt(np.mean(sol.fun**2)))
    sigma_v = 0.0
    if free:
        dof = max(1, sol.fun.size - len(x0))
        try:
            cov = np.linalg.inv(sol.jac.T @ sol.jac) * float(np.sum(sol.fun**2)) / dof
            ell = _correlation_length(sol.fun.reshape(y.shape))
            sigma_v = float(math.sqrt(max(cov[3, 3], 0.0) * ell)) * unit_v
        except np.linalg.LinAlgError:
            sigma_v = math.inf
    # back to the full-size frame: the crop's centre sits (crop_r, crop_c) pixels off the frame's
    alpha = z / (z + d_mm)
    p_full = p_work / b
    dx += alpha * crop_c * p_full
    dy += alpha * crop_r * p_full
    shadow_px = delta * (z + d_mm) / (z * p_full)

    problems = []
    if best.sigma_x < FLOOR_SIGMA or best.sigma_y < FLOOR_SIGMA:
        problems.append(
            f"the pattern is not clearly found: the best mounting scores {best.sigma_x:.1f} (x) and "
            f"{best.sigma_y:.1f} (y) random-mask spreads above what random masks score on this image "
            f"(floor {FLOOR_SIGMA:g} on each axis); check the design (phi, phi_rows, feature_um), the "
            "geometry and the frame (a flat field, dark subtracted)")
    if runner is not None and best.sigma - runner.sigma < MARGIN_SIGMA:
        problems.append(
            f"the best mounting ({orientation.name}, {best.sigma:.1f} spreads) does not beat the "
            f"runner-up ({runner.orientation.name}, {runner.sigma:.1f}) by the required margin "
            f"of {MARGIN_SIGMA:g} random-mask spreads")
    value = z if unknown == "z" else p_full
    if free and not (lo - 1e-9 <= value <= hi + 1e-9):
        what = "z" if unknown == "z" else "pixel pitch"
        problems.append(f"the fitted {what} {value:.4f} left the declared bounds [{lo:.4f}, {hi:.4f}]")
    ambiguities = _design_ambiguities(phi, phi_rows)
    say("done")
    fit = {"rows": best.score_y, "cols": best.score_x, "rel_rms": rel_rms, "turn_scan_deg": turn,
           "binning": float(b), "shadow_px_per_cell": shadow_px,
           "null_mean_x": mu["x"], "null_std_x": sd["x"], "null_mean_y": mu["y"], "null_std_y": sd["y"]}
    return PoseEstimate(orientation, dx, dy, angle, z, fit, pixel_pitch_um=p_full, unknown=unknown,
                        scale_sigma=sigma_v, hypotheses=hyps, runner_up=runner, confident=not problems,
                        problems=problems, ambiguities=ambiguities,
                        bounds=(lo, hi) if free else None)
