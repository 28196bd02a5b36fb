"""The paper's mask fitness (§III-C-1, §V-B): simulated reconstruction quality of a φ.

For a gene φ the coding matrices ``Pc(φ)``, ``Qc(φ)`` come from direct generation
(:mod:`thintact_sdk.reconstruction.direct_generation`); the simulated coding measurement of a
ground-truth scene is ``Yc = Pc X Qcᵀ + noise``; ``X̂`` is the closed-form Tikhonov solution
(paper eq. 12); and::

    fitness = harmonic_mean(f_SSIM(USAF), f_SSIM(white))
              + mean(f_PSNR(USAF), f_PSNR(white)) + f_GRAD(white)

with ``f_SSIM = 1 / (1 − SSIM)``, ``f_PSNR = PSNR`` (dB, peak 1) and
``f_GRAD = 2MN / (‖G_u X̂‖₁ + ‖G_v X̂‖₁)`` on the white reconstruction.

Speed (one evaluation per individual, paper scale R×N = 1024×400, S×M = 1280×512):

- The closed form only needs the right singular vectors and the squared singular values,
  i.e. the eigen-decomposition of the Gram matrices ``PcᵀPc`` (N×N) and ``QcᵀQc`` (M×M),
  which is several times cheaper than the SVD of the tall matrices.
- The noiseless part of the coefficients is ``Λ_P (V_Pᵀ X V_Q) Λ_Q``: ``Yc`` never has to be
  formed at sensor size.
- Noise is spatially white Gaussian with the variance of the profile's noise model
  (CONTRACTS §4: Poisson photo-electrons + read noise) at the mean signal of the scene. For
  white noise ``E``, ``U_Pᵀ E U_Q`` is again white, so its projection ``Σ_P U_Pᵀ E U_Q Σ_Q``
  is drawn directly as ``σ·√λ_P Z √λ_Qᵀ`` with one fixed ``N × M`` standard-normal ``Z`` per
  scene (common random numbers: every individual sees the same noise draw, so fitness is
  deterministic and comparisons are fair).
- τ is fixed per device (not per individual): the Wiener value ``σ² / prior_var`` in the
  matrices' units, so a mask is judged by the noise resistance of its system matrices.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter

from thintact_sdk.algorithms import (
    AxisGeometry,
    DirectGenerator,
    default_white_level_dn,
    psnr,
    signal_variance_dn,
    usaf,
    white,
)
from thintact_sdk.errors import InvalidShapeError, InvalidValueError
from thintact_sdk.plugin_support import Profile

#: Floor of 1 − SSIM and of the white image's total variation (keeps f finite for a
#: perfect reconstruction).
_EPS = 1e-9


@dataclass
class FitnessSettings:
    """How the fitness simulates and reconstructs.

    Attributes
    ----------
    white_level_dn
        DN above black at the brightest pixel of the white scene through the mask (about
        half the fully-open response); default ``0.6·(saturation − black)`` as the virtual camera.
    noise
        Add the sensor noise (default true); false gives noiseless measurements.
    frames_averaged
        Number of frames averaged per measurement (the paper averages 100); divides the
        noise variance.
    noise_seed
        Seed of the fixed standard-normal draws.
    prior_var
        Scene prior variance (display units²) in the Wiener choice of τ.
    tau
        Regularisation weight in the matrices' units (relative irradiance²); ``None`` picks
        ``σ_rel² / prior_var`` (noisy) or 1e-9 (noiseless).
    d_stripe_px
        Stripe width for direct generation; ``None`` uses its tuned default.
    dtype
        ``"float64"`` or ``"float32"`` for the Gram eigen-decompositions and products.
    """

    white_level_dn: float | None = None
    noise: bool = True
    frames_averaged: int = 100
    noise_seed: int = 0
    prior_var: float = 0.1
    tau: float | None = None
    d_stripe_px: float | None = None
    dtype: str = "float64"

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable settings."""
        return asdict(self)


@dataclass
class Evaluation:
    """The fitness of one φ and its parts (reconstructions kept only when asked).

    Attributes
    ----------
    fitness
        The paper's combined fitness.
    parts
        ``ssim_usaf``, ``ssim_white``, ``psnr_usaf``, ``psnr_white`` (dB), ``f_grad``,
        ``uniformity_white`` (1 − std/mean of the white reconstruction).
    reconstructions
        ``{"usaf": N×M, "white": N×M}`` when requested.
    """

    fitness: float
    parts: dict[str, float]
    reconstructions: dict[str, np.ndarray] = field(default_factory=dict)


class SSIMReference:
    """SSIM against one fixed ground truth, identical to :func:`thintact_sdk.reconstruction.metrics.ssim`
    (11-tap Gaussian window, σ = 1.5 px, peak 1) with the truth's local statistics computed
    once: three Gaussian filterings per estimate instead of five.

    Parameters
    ----------
    truth
        ``N × M`` ground truth in display units.
    """

    def __init__(self, truth: np.ndarray, data_range: float = 1.0, sigma: float = 1.5) -> None:
        self.sigma = sigma
        self.truth = np.asarray(truth, np.float64)
        self.c1 = (0.01 * data_range) ** 2
        self.c2 = (0.03 * data_range) ** 2
        self.my = self._f(self.truth)
        self.syy = self._f(self.truth * self.truth) - self.my * self.my

    def _f(self, a: np.ndarray) -> np.ndarray:
        return np.asarray(gaussian_filter(a, self.sigma, truncate=3.5, mode="reflect"))

    def __call__(self, estimate: np.ndarray) -> float:
        """SSIM of ``estimate`` (``N × M``) against the truth."""
        x = np.asarray(estimate, np.float64)
        mx = self._f(x)
        sxx = self._f(x * x) - mx * mx
        sxy = self._f(x * self.truth) - mx * self.my
        num = (2 * mx * self.my + self.c1) * (2 * sxy + self.c2)
        den = (mx * mx + self.my * self.my + self.c1) * (sxx + self.syy + self.c2)
        return float(np.mean(num / den))


def f_ssim(value: float) -> float:
    """``1 / (1 − SSIM)``, with 1 − SSIM floored at 1e-9."""
    return 1.0 / max(1.0 - value, _EPS)


def f_grad(image: np.ndarray) -> float:
    """``2MN / (‖G_u X‖₁ + ‖G_v X‖₁)`` for an ``N × M`` image (forward differences)."""
    n, m = image.shape
    tv = float(np.abs(np.diff(image, axis=1)).sum() + np.abs(np.diff(image, axis=0)).sum())
    return 2.0 * n * m / max(tv, _EPS)


def combine(parts: dict[str, float]) -> float:
    """The paper's fitness from its parts (harmonic mean of f_SSIM + mean PSNR + f_GRAD)."""
    fu, fw = f_ssim(parts["ssim_usaf"]), f_ssim(parts["ssim_white"])
    return 2.0 * fu * fw / (fu + fw) + 0.5 * (parts["psnr_usaf"] + parts["psnr_white"]) + parts["f_grad"]


def sign_reference(n: int) -> np.ndarray:
    """A fixed generic length-``n`` vector (seeded): eigenvectors are oriented against it."""
    return np.random.default_rng(20261124).standard_normal(n)


def canonical_signs(v: np.ndarray) -> np.ndarray:
    """``±1`` per eigenvector (column of ``... × n × k`` ``v``) making its projection on the fixed
    :func:`sign_reference` positive. The fixed noise draw lives in the Gram eigenbases, and an
    eigenvector's sign is the LAPACK implementation's choice; with this convention the fitness
    is the same draw whatever library and precision computed the eigenvectors (numpy here,
    torch on a GPU). A projection on a generic vector is far from 0, unlike a comparison of
    entries, so rounding does not flip the choice."""
    proj = np.einsum("...nk,n->...k", v, sign_reference(v.shape[-2]).astype(v.dtype))
    return np.where(proj < 0, -1.0, 1.0).astype(v.dtype)[..., None, :]


class FitnessEvaluator:
    """Evaluates the fitness of mask vectors for one device.

    Parameters
    ----------
    profile
        Device profile (grids, pitches, mask feature size, distances, noise).
    K
        Mask length (default the profile's).
    settings
        :class:`FitnessSettings`.
    """

    def __init__(self, profile: Profile, K: int | None = None,  # noqa: N803
                 settings: FitnessSettings | None = None) -> None:
        self.profile = profile
        self.settings = settings or FitnessSettings()
        self.K = int(profile.mask.K if K is None else K)
        s = self.settings
        self._dtype = np.dtype(s.dtype)
        self.gen_p = DirectGenerator(AxisGeometry.rows_of(profile, self.K), s.d_stripe_px)
        self.gen_q = DirectGenerator(AxisGeometry.cols_of(profile, self.K), s.d_stripe_px)
        n, m = profile.scene.rows, profile.scene.cols
        self.scenes: dict[str, np.ndarray] = {
            "usaf": usaf(n, m)[..., 0].astype(np.float64),
            "white": white(n, m)[..., 0].astype(np.float64),
        }
        noise = profile.noise
        white_dn = s.white_level_dn if s.white_level_dn is not None else default_white_level_dn(noise)
        if s.frames_averaged < 1:
            raise InvalidValueError(f"frames_averaged must be >= 1, got {s.frames_averaged}")
        if not white_dn > 0:
            raise InvalidValueError(f"white_level_dn must be > 0, got {white_dn}")
        self.white_level_dn = float(white_dn)
        #: DN per relative-irradiance unit: the fully open white response is 2× the white level
        self.dn_per_unit = 2.0 * self.white_level_dn
        po, qo = self.gen_p.open(), self.gen_q.open()
        rng = np.random.default_rng(s.noise_seed)
        self.sigma_rel: dict[str, float] = {}
        self.noise_draws: dict[str, np.ndarray] = {}
        for name, x in self.scenes.items():
            mean_dn = self.dn_per_unit * float((po @ x @ qo.T).mean())  # open half ≈ mean signal
            var_dn = float(signal_variance_dn(mean_dn, noise, s.frames_averaged))
            self.sigma_rel[name] = math.sqrt(var_dn) / self.dn_per_unit if s.noise else 0.0
            self.noise_draws[name] = rng.standard_normal((n, m))
        if s.tau is not None:
            self.tau = float(s.tau)
        elif s.noise:
            self.tau = self.sigma_rel["white"] ** 2 / s.prior_var
        else:
            self.tau = 1e-9
        if not self.tau > 0:
            raise InvalidValueError(f"tau must be > 0, got {self.tau}")
        self._ssim = {k: SSIMReference(v) for k, v in self.scenes.items()}
        self._cast_scenes = {k: v.astype(self._dtype) for k, v in self.scenes.items()}
        self._cast_noise = {k: v.astype(self._dtype) for k, v in self.noise_draws.items()}

    @property
    def ssim_references(self) -> dict[str, SSIMReference]:
        """The cached-statistics SSIM of each scene, ``{"usaf", "white"}``."""
        return self._ssim

    def coding_matrices(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``Pc`` (R × N) and ``Qc`` (S × M) of φ, relative irradiance per display unit."""
        return self.gen_p.coding(phi), self.gen_q.coding(phi)

    def _eig(self, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = a.astype(self._dtype, copy=False)
        lam, v = np.linalg.eigh(a.T @ a)
        return np.maximum(lam, 0.0), v * canonical_signs(v)

    def reconstruct(self, phi: np.ndarray) -> dict[str, np.ndarray]:
        """Tikhonov reconstructions ``{"usaf", "white"}`` (``N × M`` float64) for φ."""
        return self.reconstruct_from(*self.coding_matrices(phi))

    def reconstruct_from(self, pc: np.ndarray, qc: np.ndarray) -> dict[str, np.ndarray]:
        """Reconstructions for given coding matrices (``R × N``, ``S × M``, relative units)."""
        lam_p, vp = self._eig(pc)
        lam_q, vq = self._eig(qc)
        gain = np.outer(lam_p, lam_q)
        inv = 1.0 / (gain + self.tau)
        amp = np.sqrt(gain)
        out = {}
        for name, x in self._cast_scenes.items():
            if name == "white":  # 1·1ᵀ projects to an outer product
                proj = np.outer(vp.sum(axis=0), vq.sum(axis=0))
            else:
                proj = vp.T @ x @ vq
            core = gain * proj
            if self.sigma_rel[name] > 0:
                core += self.sigma_rel[name] * amp * self._cast_noise[name]
            core *= inv
            out[name] = np.asarray(vp @ core @ vq.T, np.float64)
        return out

    def evaluate(self, phi: np.ndarray, keep_reconstructions: bool = False) -> Evaluation:
        """Fitness of one φ (``(K,)`` ±1)."""
        phi = np.asarray(phi)
        if phi.shape != (self.K,):
            raise InvalidShapeError(f"phi must have shape ({self.K},), got {phi.shape}")
        return self.score(self.reconstruct(phi), keep_reconstructions)

    def evaluate_matrices(self, pc: np.ndarray, qc: np.ndarray,
                          keep_reconstructions: bool = False) -> Evaluation:
        """Fitness of given coding matrices (e.g. from the exact simulator), relative units."""
        return self.score(self.reconstruct_from(pc, qc), keep_reconstructions)

    def score(self, rec: dict[str, np.ndarray], keep_reconstructions: bool = False) -> Evaluation:
        """Fitness and its parts from the reconstructions ``{"usaf", "white"}``."""
        white = rec["white"]
        parts = {
            "ssim_usaf": self._ssim["usaf"](rec["usaf"]),
            "ssim_white": self._ssim["white"](white),
            "psnr_usaf": psnr(rec["usaf"], self.scenes["usaf"]),
            "psnr_white": psnr(white, self.scenes["white"]),
            "f_grad": f_grad(white),
            "uniformity_white": 1.0 - float(white.std() / max(abs(float(white.mean())), _EPS)),
        }
        return Evaluation(combine(parts), parts, rec if keep_reconstructions else {})

    def fitness(self, phi: np.ndarray) -> float:
        """The combined fitness of one φ."""
        return self.evaluate(phi).fitness

    def describe(self) -> dict[str, Any]:
        """Settings and derived constants (for provenance)."""
        return {"K": self.K, "tau": self.tau, "white_level_dn": self.white_level_dn,
                "sigma_rel": dict(self.sigma_rel),
                "d_stripe_px": [self.gen_p.stripe.d_stripe_px, self.gen_q.stripe.d_stripe_px],
                **self.settings.to_dict()}
