"""Fitting the tactile forward model (:mod:`.model`) to real press frames.

Linear parameters (illumination field, texture strength, exposures, light vectors, lobe
strengths, crosstalk) are fitted by weighted least squares, block by block, alternating a few
times; nonlinear ones (camera γ, elastomer σ_e, lobe shininess) by a scan around the current
value; the press nuisances (centre, depth) per press by Nelder–Mead on a window around it.
Weights are 1/σ² of the per-pixel noise (measured, per channel), carried through the inverse
camera response when γ ≠ 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from thintact_sdk.diagnosis.core.residual_stats import FitStats, fit_stats
from thintact_sdk.diagnosis.tactile.press_model import (
    Normals,
    Press,
    TactileModel,
    ball_normals,
    polynomial_basis,
    texture_map,
)

MAX_FIELD_ORDER = 4


@dataclass
class PressData:
    """Real press frames prepared for fitting.

    Attributes
    ----------
    images
        ``P × H × W × 3`` float64 in [0, 1].
    reference
        ``H × W × 3`` no-contact frame.
    valid
        ``P × H × W × 3`` values used (not clipped at 0 or 1).
    sigma
        ``3`` per-pixel noise standard deviation per channel (display units).
    mm_per_px, ball_radius_mm
        Pixel size and indenter radius, mm.
    """

    images: np.ndarray
    reference: np.ndarray
    valid: np.ndarray
    sigma: np.ndarray
    mm_per_px: float
    ball_radius_mm: float

    def __post_init__(self) -> None:
        h, w = self.images.shape[1:3]
        self.basis = polynomial_basis(h, w, MAX_FIELD_ORDER)
        self.texture = texture_map(self.reference)

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.images.shape[1]), int(self.images.shape[2])


def clipped_mask(images: np.ndarray) -> np.ndarray:
    """Values not clipped by the 8-bit range (strictly inside (0.5, 254.5) / 255)."""
    return (images > 0.5 / 255) & (images < 254.5 / 255)


def all_normals(data: PressData, presses: list[Press], sigma_mm: float,
                skirt_mm: float = 0.0) -> list[Normals]:
    """Normals of every press under the current nuisances (surface blur σ_e, sink-in skirt)."""
    return [ball_normals(data.shape, p, data.ball_radius_mm, data.mm_per_px, sigma_mm, skirt_mm)
            for p in presses]


def predict(model: TactileModel, data: PressData, normals: list[Normals]) -> np.ndarray:
    """``P × H × W × 3`` predicted frames."""
    bg = model.background(data.basis, data.texture)
    return np.stack([model.respond(model.linear(model.shading(n), bg, i))
                     for i, n in enumerate(normals)])


def variance(model: TactileModel, data: PressData, pred: np.ndarray) -> np.ndarray:
    """Noise variance of measured − predicted: the camera noise, plus the no-contact frame's
    own noise where the model borrows its texture (``α² σ² (pred / reference)²``)."""
    var = np.broadcast_to(data.sigma**2, pred.shape).copy()
    if np.any(model.texture_strength):
        ratio = pred / np.maximum(data.reference, 0.05)
        var += (model.texture_strength * data.sigma * ratio) ** 2
    return var


@dataclass
class Score:
    """Statistics of one fitted model: contract χ² (:class:`FitStats`) and BIC."""

    stats: FitStats
    neg2loglike: float
    n_params: int
    bic: float

    @property
    def chi2_per_dof(self) -> float:
        return self.stats.chi2_per_dof


def n_params(model: TactileModel, n_frames: int) -> int:
    """Free parameters of ``model`` (nuisances included: 3 per press)."""
    k = 3 * model.field_coef.shape[1] + 3 * n_frames
    eff = set(model.effects)
    k += 3 if "background_texture" in eff else 0
    k += 3 * (n_frames - 1) if "exposure_drift" in eff else 0
    k += 9 if "led_directions" in eff else 0
    k += 4 if "specular_lobe" in eff else 0
    k += 6 if "colour_crosstalk" in eff else 0
    k += 1 if "camera_gamma" in eff else 0
    k += 1 if "elastomer_blur" in eff else 0
    k += 1 if "optical_spread" in eff else 0
    k += 1 if "gel_sink_in" in eff else 0
    return k


def score(model: TactileModel, data: PressData, normals: list[Normals]) -> tuple[Score, np.ndarray]:
    """Score of ``model`` and its prediction."""
    pred = predict(model, data, normals)
    var = variance(model, data, pred)
    st = fit_stats(data.images, pred, var, data.valid)
    n2ll = st.chi2_per_dof * st.n_pixels + float(np.sum(np.log(var[data.valid])))
    k = n_params(model, len(data.images))
    return Score(st, n2ll, k, n2ll + k * float(np.log(max(st.n_pixels, 2)))), pred


def _targets(model: TactileModel, data: PressData) -> tuple[np.ndarray, np.ndarray]:
    """Data and weights in the linear domain (through the inverse camera response)."""
    y = data.images
    w = np.where(data.valid, 1.0, 0.0) / data.sigma**2
    if model.gamma != 1.0:
        g = model.gamma
        yl = np.clip(y, 1e-3, None) ** (1.0 / g)
        dy = yl / (g * np.clip(y, 1e-3, None))  # d y_lin / d y
        return yl, w / dy**2
    return y, w


def fit_linear(model: TactileModel, data: PressData, normals: list[Normals],
               iterations: int = 4) -> TactileModel:
    """Fit the linear parameters of ``model``'s effects (alternating weighted least squares);
    returns a new model."""
    m = model.copy()
    eff = set(m.effects)
    y, w = _targets(m, data)
    n_frames = len(y)
    base = np.stack([m.shading_base(n) for n in normals])  # P × H × W × 3 (light fixed)
    k = m.field_coef.shape[1]
    phi = data.basis[:k]
    for _ in range(iterations):
        shading = base if np.allclose(m.crosstalk, np.eye(3)) else (
            1.0 + np.einsum("ck,phwk->phwc", m.crosstalk, base - 1.0))
        expo = np.ones((n_frames, 1, 1, 3)) if m.exposure is None else m.exposure[:, None, None, :]
        tex = 1.0 + m.texture_strength * data.texture
        # illumination field
        mm = tex * expo * shading
        q = np.sum(w * mm * mm, axis=0)  # H × W × 3
        r = np.sum(w * y * mm, axis=0)
        for c in range(3):
            a = np.einsum("khw,lhw,hw->kl", phi, phi, q[..., c])
            b = np.einsum("khw,hw->k", phi, r[..., c])
            m.field_coef[c] = np.linalg.solve(a + 1e-12 * np.eye(k), b)
        field = np.einsum("ck,khw->hwc", m.field_coef, phi)
        if "background_texture" in eff:
            m0 = field * expo * shading
            mt = m0 * data.texture
            num = np.sum(w * (y - m0) * mt, axis=(0, 1, 2))
            den = np.sum(w * mt * mt, axis=(0, 1, 2))
            m.texture_strength = num / np.maximum(den, 1e-12)
            tex = 1.0 + m.texture_strength * data.texture
        bg = field * tex
        if "exposure_drift" in eff:
            mm = bg * shading
            e = np.sum(w * y * mm, axis=(1, 2)) / np.maximum(np.sum(w * mm * mm, axis=(1, 2)), 1e-12)
            scale = e.mean(axis=0)
            m.exposure = e / scale
            m.field_coef *= scale[:, None]
            bg = bg * scale
            expo = m.exposure[:, None, None, :]
        # shading parameters
        denom = bg * expo
        z = y / np.where(np.abs(denom) > 1e-6, denom, 1e-6)
        wz = w * denom * denom
        if "led_directions" in eff:
            # the design columns as the shading sees them (through the optical spread)
            nx = np.stack([m.spread(n.nx, n) for n in normals])
            ny = np.stack([m.spread(n.ny, n) for n in normals])
            nz = np.stack([m.spread(n.nz - 1.0, n) for n in normals])
            cols = [nx, ny, nz]
            lobe = None
            if "specular_lobe" in eff:
                lobe = np.stack([m.spread(m.lobe(n), n) for n in normals])
            light = np.zeros((3, 3)) if m.light is None else m.light
            spec = m.specular.copy()
            for c in range(3):
                design = cols + ([lobe[..., c]] if lobe is not None else [])
                a = np.array([[np.sum(wz[..., c] * u * v) for v in design] for u in design])
                b = np.array([np.sum(wz[..., c] * (z[..., c] - 1.0) * u) for u in design])
                sol = np.linalg.solve(a + 1e-12 * np.eye(len(design)), b)
                light[c] = sol[:3]
                if lobe is not None:
                    spec[c] = sol[3]
            m.light, m.specular = light, spec
            base = np.stack([m.shading_base(n) for n in normals])
        if "colour_crosstalk" in eff:
            d = base - 1.0
            mix = np.eye(3)
            for c in range(3):
                others = [kk for kk in range(3) if kk != c]
                design = [d[..., kk] for kk in others]
                a = np.array([[np.sum(wz[..., c] * u * v) for v in design] for u in design])
                b = np.array([np.sum(wz[..., c] * (z[..., c] - 1.0 - d[..., c]) * u) for u in design])
                sol = np.linalg.solve(a + 1e-12 * np.eye(2), b)
                mix[c, others] = sol
            m.crosstalk = mix
    return m


def _window(shape: tuple[int, int], press: Press, half: int) -> tuple[slice, slice]:
    r0 = int(np.clip(round(press.row) - half, 0, shape[0] - 1))
    c0 = int(np.clip(round(press.col) - half, 0, shape[1] - 1))
    return slice(r0, min(shape[0], r0 + 2 * half)), slice(c0, min(shape[1], c0 + 2 * half))


def fit_presses(model: TactileModel, data: PressData, presses: list[Press],
                max_iter: int = 150) -> list[Press]:
    """Refit each press's centre and depth under ``model`` (Nelder–Mead on a window of
    ±(ball radius + 4 (σ_e + σ_o + L) + 4 px) around it; centres within ±1 ball radius of the start,
    depths 0.02 mm .. 0.95 ball radius)."""
    bg = model.background(data.basis, data.texture)
    r_px = data.ball_radius_mm / data.mm_per_px
    half = int(np.ceil(r_px + 4 * (model.sigma_mm + model.spread_mm + model.skirt_mm)
                       / data.mm_per_px + 4))
    y, w = data.images, np.where(data.valid, 1.0, 0.0) / data.sigma**2
    out = []
    for i, p0 in enumerate(presses):
        rs, cs = _window(data.shape, p0, half)
        win_shape = (rs.stop - rs.start, cs.stop - cs.start)
        yw, ww, bw = y[i, rs, cs], w[i, rs, cs], bg[rs, cs]

        def cost(v: np.ndarray, p0: Press = p0, rs: slice = rs, cs: slice = cs,
                 yw: np.ndarray = yw, ww: np.ndarray = ww, bw: np.ndarray = bw,
                 i: int = i, win_shape: tuple[int, int] = win_shape) -> float:
            row, col, depth = float(v[0]), float(v[1]), float(v[2])
            if (abs(row - p0.row) > r_px or abs(col - p0.col) > r_px
                    or not 0.02 <= depth <= 0.95 * data.ball_radius_mm):
                return 1e30
            nrm = ball_normals(win_shape, Press(row - rs.start, col - cs.start, depth),
                               data.ball_radius_mm, data.mm_per_px, model.sigma_mm,
                               model.skirt_mm)
            pred = model.respond(model.linear(model.shading(nrm), bw, i))
            return float(np.sum(ww * (yw - pred) ** 2))

        res = minimize(cost, np.array([p0.row, p0.col, p0.depth_mm]), method="Nelder-Mead",
                       options={"maxiter": max_iter, "xatol": 0.05, "fatol": 1e-3,
                                "initial_simplex": np.array([
                                    [p0.row, p0.col, p0.depth_mm],
                                    [p0.row + 1.5, p0.col, p0.depth_mm],
                                    [p0.row, p0.col + 1.5, p0.depth_mm],
                                    [p0.row, p0.col, p0.depth_mm + 0.15]])})
        out.append(Press(float(res.x[0]), float(res.x[1]), float(res.x[2])))
    return out


def scan_scalar(evaluate: object, values: list[float]) -> tuple[float, float]:
    """Minimise ``evaluate(value) -> float`` over ``values``, then one parabolic step through
    the best and its neighbours (evaluated); returns ``(best value, best cost)``."""
    f = evaluate  # typed loosely: a callable float -> float
    costs = [f(v) for v in values]  # type: ignore[operator]
    j = int(np.argmin(costs))
    best_v, best_c = values[j], costs[j]
    if 0 < j < len(values) - 1:
        x0, x1, x2 = values[j - 1], values[j], values[j + 1]
        y0, y1, y2 = costs[j - 1], costs[j], costs[j + 1]
        den = (x0 - x1) * (x0 - x2) * (x1 - x2)
        a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
        b = (x2**2 * (y0 - y1) + x1**2 * (y2 - y0) + x0**2 * (y1 - y2)) / den
        if a > 0:
            xv = float(np.clip(-b / (2 * a), x0, x2))
            cv = f(xv)  # type: ignore[operator]
            if cv < best_c:
                best_v, best_c = xv, cv
    return float(best_v), float(best_c)
