"""Linear elastic half-space model of the elastomer: the forward mechanics behind force truth.

The tactile simulator shapes the membrane geometrically (rigid indentation smoothed by a
Gaussian) and knows no forces. This module computes them independently from the same
press, with the textbook model of a linear elastic half-space (Johnson, *Contact
Mechanics*, 1985):

* normal contact: the pressure ``p ≥ 0`` under a rigid indenter pressed ``d`` into the
  surface solves the Boussinesq contact problem on the pixel grid (surface displacement
  = interference where ``p > 0``, no penetration elsewhere), by the projected conjugate
  gradient of Polonsky & Keer (Wear 231, 1999) with FFT convolutions;
* tangential load with partial slip: the Cattaneo–Mindlin solution generalised to any
  indenter shape (Jäger 1998; Ciavarella 1998): traction ``q = μ (p(d) − p(d*))`` along
  the shear direction, the stick zone being the contact area at the smaller indentation
  ``d*``; the surface displacement follows from Cerruti's point-load solution.

All lengths are mm, moduli MPa (= N/mm²), pressures MPa, forces N.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thintact_sdk.formats.profiles import Profile

SQUARE_SELF = 4.0 * np.log(1.0 + np.sqrt(2.0))
"""∫∫ 1/r over a unit square seen from its centre (= 3.5255): the pixel's own influence."""


@dataclass(frozen=True)
class Elastomer:
    """Material of the gel (``tactile.elastomer_youngs_mpa`` / ``elastomer_poisson``).

    Attributes
    ----------
    youngs_mpa
        Young's modulus E in MPa (silicone gels: 0.1–1 MPa; default 0.3).
    poisson
        Poisson's ratio ν (near-incompressible silicone: 0.45–0.5; default 0.48).
    """

    youngs_mpa: float = 0.3
    poisson: float = 0.48

    @property
    def contact_modulus_mpa(self) -> float:
        """E* = E / (1 − ν²) (rigid indenter), MPa."""
        return self.youngs_mpa / (1.0 - self.poisson**2)

    @property
    def shear_modulus_mpa(self) -> float:
        """G = E / (2 (1 + ν)), MPa."""
        return self.youngs_mpa / (2.0 * (1.0 + self.poisson))

    @classmethod
    def from_profile(cls, profile: Profile) -> Elastomer:
        """The profile's ``tactile.elastomer_youngs_mpa`` / ``elastomer_poisson`` (defaults)."""
        extra = (profile.tactile.model_extra or {}) if profile.tactile is not None else {}
        return cls(
            youngs_mpa=float(extra.get("elastomer_youngs_mpa", cls.youngs_mpa)),
            poisson=float(extra.get("elastomer_poisson", cls.poisson)),
        )


def _distance_grid(shape: tuple[int, int], mm_per_px: float) -> tuple[np.ndarray, ...]:
    """Wrapped (x, y, r) offsets in mm on the 2N × 2M grid used for linear convolution."""
    n, m = 2 * shape[0], 2 * shape[1]
    iy = np.fft.fftfreq(n, 1.0 / n)
    ix = np.fft.fftfreq(m, 1.0 / m)
    y, x = np.meshgrid(iy * mm_per_px, ix * mm_per_px, indexing="ij")
    return x, y, np.hypot(x, y)


class _Convolver:
    """Linear convolution of ``N × M`` fields with a kernel given on the doubled grid."""

    def __init__(self, kernel: np.ndarray, shape: tuple[int, int]) -> None:
        self.shape = shape
        self.kernel_f = np.fft.rfft2(kernel)

    def __call__(self, field: np.ndarray) -> np.ndarray:
        n, m = self.shape
        f = np.fft.rfft2(field, s=(2 * n, 2 * m))
        return np.fft.irfft2(f * self.kernel_f, s=(2 * n, 2 * m))[:n, :m]


def normal_compliance(shape: tuple[int, int], mm_per_px: float, e_star_mpa: float) -> _Convolver:
    """Boussinesq: surface displacement (mm) from pixel pressures (MPa): ``1/(π E* r)``."""
    _, _, r = _distance_grid(shape, mm_per_px)
    area = mm_per_px**2
    with np.errstate(divide="ignore"):
        k = area / (np.pi * e_star_mpa * r)
    k[0, 0] = SQUARE_SELF * mm_per_px / (np.pi * e_star_mpa)
    return _Convolver(k, shape)


def tangential_compliance(
    shape: tuple[int, int], mm_per_px: float, elastomer: Elastomer
) -> tuple[_Convolver, _Convolver, _Convolver]:
    """Cerruti: (K_xx, K_xy, K_yy) mapping pixel tractions (MPa) to tangential displacement
    (mm): ``K_xx = [(1 − ν)/r + ν x²/r³] / (2π G)`` etc."""
    x, y, r = _distance_grid(shape, mm_per_px)
    nu, g = elastomer.poisson, elastomer.shear_modulus_mpa
    area = mm_per_px**2
    with np.errstate(divide="ignore", invalid="ignore"):
        kxx = area * ((1 - nu) / r + nu * x**2 / r**3) / (2 * np.pi * g)
        kyy = area * ((1 - nu) / r + nu * y**2 / r**3) / (2 * np.pi * g)
        kxy = area * nu * x * y / r**3 / (2 * np.pi * g)
    self_term = (1 - nu / 2) * SQUARE_SELF * mm_per_px / (2 * np.pi * g)
    kxx[0, 0] = kyy[0, 0] = self_term
    kxy[0, 0] = 0.0
    return (_Convolver(kxx, shape), _Convolver(kxy, shape), _Convolver(kyy, shape))


@dataclass
class NormalContact:
    """Solution of a displacement-controlled normal contact.

    Attributes
    ----------
    pressure_mpa
        ``N × M`` contact pressure (MPa, ≥ 0).
    force_n
        Total normal force (N).
    contact
        ``N × M`` bool, pixels in contact (p > 0).
    area_mm2
        Contact area (mm²).
    iterations
        Conjugate-gradient iterations used.
    """

    pressure_mpa: np.ndarray
    force_n: float
    contact: np.ndarray
    area_mm2: float
    iterations: int


def solve_normal_contact(
    interference_mm: np.ndarray,
    mm_per_px: float,
    elastomer: Elastomer,
    tol: float = 1e-6,
    max_iter: int = 500,
) -> NormalContact:
    """Pressure under a rigid indenter (Polonsky–Keer projected conjugate gradient).

    Parameters
    ----------
    interference_mm
        ``N × M`` rigid interference ``d − gap`` (mm): positive where the undeformed
        indenter lies below the membrane surface, negative (or −inf) where it clears it.
    mm_per_px
        Grid pixel size (mm).
    elastomer
        Material (E*, via :attr:`Elastomer.contact_modulus_mpa`).
    tol
        Relative gap residual on the contact set at which iteration stops.
    """
    h = -np.nan_to_num(np.asarray(interference_mm, np.float64), neginf=-1e3)  # initial gap
    shape = h.shape
    k = normal_compliance(shape, mm_per_px, elastomer.contact_modulus_mpa)
    area = mm_per_px**2
    if not (h < 0).any():
        z = np.zeros(shape)
        return NormalContact(z, 0.0, z > 0, 0.0, 0)
    p = np.where(h < 0, -h * elastomer.contact_modulus_mpa / (SQUARE_SELF * mm_per_px), 0.0)
    t = np.zeros(shape)
    g_old, delta = 1.0, 0.0
    scale = float(-h.min())
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is reported
        gap = k(p) + h
        s = p > 0
        g_norm = float(np.sum(gap[s] ** 2))
        if np.sqrt(g_norm / max(1, int(s.sum()))) < tol * scale and not ((p == 0) & (gap < 0)).any():
            break
        t = np.where(s, gap + delta * (g_norm / g_old) * t, 0.0)
        g_old = g_norm
        r = k(t)
        denom = float(np.sum(r[s] * t[s]))
        tau = float(np.sum(gap[s] * t[s])) / denom if denom > 0 else 0.0
        p = p - tau * t
        p[p < 0] = 0.0
        overlap = (p == 0) & (gap < 0)
        if overlap.any():
            p[overlap] -= tau * gap[overlap]
            delta = 0.0
        else:
            delta = 1.0
    contact = p > 0
    return NormalContact(p, float(p.sum() * area), contact, float(contact.sum() * area), it)


def tangential_displacement(
    traction_x_mpa: np.ndarray, traction_y_mpa: np.ndarray, mm_per_px: float,
    elastomer: Elastomer,
) -> tuple[np.ndarray, np.ndarray]:
    """Surface displacement (mm) ``(u_x, u_y)`` of the half-space under tangential
    tractions (MPa), each ``N × M``."""
    kxx, kxy, kyy = tangential_compliance(traction_x_mpa.shape, mm_per_px, elastomer)
    ux = kxx(traction_x_mpa) + kxy(traction_y_mpa)
    uy = kxy(traction_x_mpa) + kyy(traction_y_mpa)
    return ux, uy
