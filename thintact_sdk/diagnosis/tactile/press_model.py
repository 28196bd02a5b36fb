"""The forward model of a real tactile frame, baseline simulation plus named effects.

For press p, pixel (x, y) and channel c (display units, [0, 1])::

    pred = ( F_c(x, y) · (1 + α_c t_c(x, y)) · E_pc · S_c(n_p(x, y)) ) ^ γ

* ``n_p`` is the membrane normal of a ball of known radius pressed at (row, col) to a depth
  (the per-press nuisances), its rigid cap (with ``gel_sink_in``, the cap plus a sink-in
  skirt around it) smoothed by the elastomer Gaussian of width σ_e (the surface's own shape);
* ``S_c`` is the shading relative to the flat membrane (1 where flat): the SDK simulator's
  Phong shading under its 10-LED layout (baseline), or a fitted Lambertian light per channel
  ``1 + u n_x + v n_y + w (n_z − 1)`` (``led_directions``), plus a Phong lobe
  (``specular_lobe``), mixed between channels (``colour_crosstalk``); with
  ``optical_spread`` its departure from 1 is blurred by a Gaussian of width σ_o (light
  scattered in the gel and the coating spreads the shading, not the surface);
* ``F_c`` is a polynomial illumination field (a constant gain in the baseline);
* ``t_c`` is the background texture: what the no-contact frame holds beyond a smooth
  (order-3 polynomial) field; ``α_c`` its strength (0 in the baseline);
* ``E_pc`` a per-frame exposure (1 in the baseline); ``γ`` the camera response (1).

The effect vocabulary that switches these terms on is in :mod:`.vocabulary`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.ndimage import gaussian_filter

from thintact_sdk.tactile.simulation.elastomer import gel_window, reach_px, smooth
from thintact_sdk.tactile.simulation.lighting import PhongShading


@dataclass(frozen=True)
class Press:
    """Nuisances of one press: centre (row, col) in px and press depth in mm."""

    row: float
    col: float
    depth_mm: float


@dataclass
class Normals:
    """Membrane normal components and slopes of one press, each ``H × W``."""

    nx: np.ndarray
    ny: np.ndarray
    nz: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    depth_mm: np.ndarray
    mm_per_px: float = 0.0


def ball_normals(shape: tuple[int, int], press: Press, ball_radius_mm: float, mm_per_px: float,
                 sigma_mm: float, skirt_mm: float = 0.0) -> Normals:
    """Normals of a ball cap pressed ``press.depth_mm`` at ``press`` (smoothed by a Gaussian of
    ``sigma_mm``), as the SDK's tactile simulator shapes the membrane. With ``skirt_mm`` > 0
    the gel sinks in around the contact (``gel_sink_in``): ``press.depth_mm`` is still the press
    depth, the ball's cap is that much less deep and the surface outside its contact radius a
    skirt ``∝ K₀(r/L)``, L = ``skirt_mm``,
    continuous in depth and slope (:class:`~thintact_sdk.tactile.calibration.ball_press.BallModel`),
    before the Gaussian. The Gaussian sees the ball and the gel beyond the frame too
    (:mod:`~thintact_sdk.tactile.simulation.elastomer`): no zero-depth border."""
    sigma_px = sigma_mm / mm_per_px
    if skirt_mm > 0:
        from scipy.optimize import brentq

        from thintact_sdk.tactile.calibration.ball_press import BallModel

        model = BallModel("sink-in", skirt_mm)
        zero = np.zeros(1)

        def total(h: float) -> float:  # the press depth of a cap of height h, skirt included
            return model.rigid_depth(zero, h, ball_radius_mm)[1] - press.depth_mm

        top = min(press.depth_mm, ball_radius_mm)
        h = brentq(total, 0.0, top, xtol=1e-6) if top > 0 and total(top) > 0 else top

    def sharp(rr: np.ndarray, cc: np.ndarray) -> np.ndarray:
        r2 = ((rr - press.row) ** 2 + (cc - press.col) ** 2) * mm_per_px**2
        if skirt_mm > 0:
            return model.rigid_depth(np.sqrt(r2), h, ball_radius_mm)[0]
        cap = np.sqrt(np.clip(ball_radius_mm**2 - r2, 0.0, None)) - (ball_radius_mm - press.depth_mm)
        return np.clip(cap, 0.0, None)

    # + 1: central differences at the frame's edge
    shape_on_gel, win = gel_window(sharp, shape, reach_px(sigma_px) + 1, grow=reach_px(sigma_px) + 1)
    smoothed = smooth(shape_on_gel, sigma_px)
    gy, gx = (win.frame(g) for g in np.gradient(smoothed, mm_per_px))
    depth = win.frame(smoothed)
    norm = np.sqrt(1.0 + gx * gx + gy * gy)
    return Normals(-gx / norm, -gy / norm, 1.0 / norm, gx, gy, depth, mm_per_px)


def polynomial_basis(height: int, width: int, order: int) -> np.ndarray:
    """``K × H × W`` monomials x^i y^j, i + j ≤ ``order``, x and y in [−1, 1]."""
    y, x = np.meshgrid(np.linspace(-1, 1, height), np.linspace(-1, 1, width), indexing="ij")
    return np.stack([x**i * y ** (d - i) for d in range(order + 1) for i in range(d + 1)])


def texture_map(reference: np.ndarray, order: int = 3) -> np.ndarray:
    """``H × W × 3`` relative texture of the no-contact frame: ``reference / P − 1`` with ``P``
    its per-channel least-squares polynomial of total order ``order``."""
    h, w, c = reference.shape
    basis = polynomial_basis(h, w, order).reshape(-1, h * w).T
    out = np.empty(reference.shape)
    for k in range(c):
        coef, *_ = np.linalg.lstsq(basis, reference[..., k].reshape(-1), rcond=None)
        smooth = np.maximum((basis @ coef).reshape(h, w), 1e-3)
        out[..., k] = reference[..., k] / smooth - 1.0
    return out


_BASELINE_PHONG = PhongShading()


def phong_ratio(nrm: Normals) -> np.ndarray:
    """The SDK simulator's shading (10 LEDs, Phong) relative to the flat membrane, ``H × W × 3``."""
    flat = _BASELINE_PHONG.shade(np.zeros((1, 1)), np.zeros((1, 1)))[0, 0].astype(np.float64)
    return _BASELINE_PHONG.shade(nrm.gx, nrm.gy).astype(np.float64) / np.maximum(flat, 1e-6)


@dataclass
class TactileModel:
    """Parameters of the forward model (module docstring). Linear parameters are per channel.

    Attributes
    ----------
    effects
        Names of the effects switched on, in the order accepted.
    field_coef
        ``3 × K`` polynomial coefficients of ``F_c`` (K = 1: a constant gain).
    texture_strength
        ``3`` values α_c.
    exposure
        ``P × 3`` per-frame gains (ones in the baseline).
    light
        ``3 × 3`` (u, v, w) per channel, or None for the baseline Phong shading.
    specular
        ``3`` lobe strengths k_c (relative to the flat level).
    shininess
        Phong exponent of the lobe.
    crosstalk
        ``3 × 3`` channel mixing of ``S − 1`` (identity: none).
    gamma
        Camera response exponent.
    sigma_mm
        Elastomer blur width σ_e, mm: smooths the surface (its depth and normals).
    spread_mm
        Optical spread σ_o, mm: blurs the shading's departure from the flat level (0: none).
    skirt_mm
        Sink-in skirt length L, mm (``gel_sink_in``; 0: the rigid cap).
    """

    effects: list[str] = field(default_factory=list)
    field_coef: np.ndarray = field(default_factory=lambda: np.full((3, 1), 0.5))
    texture_strength: np.ndarray = field(default_factory=lambda: np.zeros(3))
    exposure: np.ndarray | None = None
    light: np.ndarray | None = None
    specular: np.ndarray = field(default_factory=lambda: np.zeros(3))
    shininess: float = 10.0
    crosstalk: np.ndarray = field(default_factory=lambda: np.eye(3))
    gamma: float = 1.0
    sigma_mm: float = 0.25
    spread_mm: float = 0.0
    skirt_mm: float = 0.0

    def spread(self, values: np.ndarray, nrm: Normals) -> np.ndarray:
        """``values`` (``H × W`` or ``H × W × C``, departures from the flat level) blurred by
        the optical spread σ_o (``nearest`` edges); unchanged when σ_o is 0."""
        if self.spread_mm <= 0:
            return values
        if nrm.mm_per_px <= 0:
            raise ValueError("optical spread needs the normals' pixel size")
        s = self.spread_mm / nrm.mm_per_px
        return gaussian_filter(values, (s, s, 0)[: values.ndim], mode="nearest")

    def copy(self) -> TactileModel:
        """A deep copy."""
        return replace(
            self, effects=list(self.effects), field_coef=self.field_coef.copy(),
            texture_strength=self.texture_strength.copy(),
            exposure=None if self.exposure is None else self.exposure.copy(),
            light=None if self.light is None else self.light.copy(),
            specular=self.specular.copy(), crosstalk=self.crosstalk.copy())

    @property
    def field_order(self) -> int:
        """Polynomial order of ``F_c``."""
        k = self.field_coef.shape[1]
        order = 0
        while (order + 1) * (order + 2) // 2 < k:
            order += 1
        return order

    def light_dirs(self) -> np.ndarray:
        """``3 × 3`` unit light direction per channel (the fitted one, else the mean of that
        colour's LEDs in the SDK layout)."""
        if self.light is not None:
            v = self.light.copy()
        else:
            v = np.zeros((3, 3))
            for led in _BASELINE_PHONG.leds:
                v += np.outer(np.asarray(led.color), led.direction())
        return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)

    def shading_base(self, nrm: Normals) -> np.ndarray:
        """``H × W × 3`` shading before crosstalk: the baseline Phong ratio, or the fitted
        Lambertian light per channel plus its lobe."""
        if self.light is None:
            return 1.0 + self.spread(phong_ratio(nrm) - 1.0, nrm)
        base = (self.light[:, 0] * nrm.nx[..., None] + self.light[:, 1] * nrm.ny[..., None]
                + self.light[:, 2] * (nrm.nz[..., None] - 1.0))
        if np.any(self.specular):
            base = base + self.specular * self.lobe(nrm)
        return 1.0 + self.spread(base, nrm)

    def lobe(self, nrm: Normals) -> np.ndarray:
        """``H × W × 3`` Phong lobe ``max(0, r·v)^α`` minus its flat value, per channel light."""
        dirs = self.light_dirs()
        out = np.empty(nrm.nx.shape + (3,))
        for c in range(3):
            lx, ly, lz = dirs[c]
            ndotl = lx * nrm.nx + ly * nrm.ny + lz * nrm.nz
            rv = np.clip(2.0 * ndotl * nrm.nz - lz, 0.0, None) ** self.shininess
            flat = max(2.0 * lz * 1.0 - lz, 0.0) ** self.shininess
            out[..., c] = np.where(ndotl > 0, rv, 0.0) - flat
        return out

    def shading(self, nrm: Normals) -> np.ndarray:
        """``H × W × 3`` shading relative to the flat membrane, crosstalk included."""
        base = self.shading_base(nrm)
        if not np.allclose(self.crosstalk, np.eye(3)):
            base = 1.0 + np.einsum("ck,hwk->hwc", self.crosstalk, base - 1.0)
        return base

    def background(self, basis: np.ndarray, texture: np.ndarray) -> np.ndarray:
        """``H × W × 3`` ``F_c · (1 + α_c t_c)``; ``basis`` from :func:`polynomial_basis` of at
        least this model's order."""
        k = self.field_coef.shape[1]
        f = np.einsum("ck,khw->hwc", self.field_coef, basis[:k])
        return f * (1.0 + self.texture_strength * texture)

    def linear(self, shading: np.ndarray, background: np.ndarray, frame: int) -> np.ndarray:
        """The signal before the camera response for frame ``frame``."""
        e = 1.0 if self.exposure is None else self.exposure[frame]
        return background * e * shading

    def respond(self, linear: np.ndarray) -> np.ndarray:
        """Camera response: ``linear^γ`` (negative values clipped)."""
        if self.gamma == 1.0:
            return linear
        return np.clip(linear, 1e-6, None) ** self.gamma
