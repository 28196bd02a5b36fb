"""Reconstruct validation frames with a calibration and score them (PSNR, SSIM); choose τ.

Reconstruction goes through the decoders plugin (``thintact-noniterative`` by default), so
the figures are what a user of the bundle gets.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from thintact_sdk.imaging.calibration_bundle import CalibrationBundle
from thintact_sdk.imaging.metrics import psnr, ssim
from thintact_sdk.interfaces import Decoder
from thintact_sdk.plugin_manager import get_registry
from thintact_sdk.profile import NoiseSpec, Profile

DEFAULT_DECODER = "thintact-noniterative"
TAU_GRID = tuple(10.0 ** e for e in range(-9, 0))
"""τ candidates relative to the largest ``σ_P² σ_Q²`` of the coding matrices."""


@dataclass
class ValidationResult:
    """One validation scene reconstructed.

    Attributes
    ----------
    label
        Frame label (or file name).
    psnr_db, ssim
        Against the displayed scene (display units, data range 1).
    estimate
        ``N × M × 3`` float32 reconstruction.
    truth
        ``N × M × 3`` float32 displayed scene.
    """

    label: str
    psnr_db: float
    ssim: float
    estimate: np.ndarray
    truth: np.ndarray


def make_decoder(
    profile: Profile, bundle: CalibrationBundle, name: str = DEFAULT_DECODER, **settings: Any
) -> Decoder:
    """Build decoder ``name`` on ``bundle`` (settings such as ``tau`` are passed through)."""
    decoder = get_registry().create("decoder", name, profile, {"bundle": bundle, **settings})
    return decoder  # type: ignore[no-any-return]


def score(label: str, estimate: np.ndarray, truth: np.ndarray) -> ValidationResult:
    """PSNR and SSIM of ``estimate`` against ``truth`` (clipped to [0, 1] first, as displayed)."""
    est = np.clip(np.asarray(estimate, np.float32), 0.0, 1.0)
    tru = np.asarray(truth, np.float32)
    return ValidationResult(label, psnr(est, tru), ssim(est, tru), est, tru)


def averaged_noise(noise: NoiseSpec, frames: int) -> NoiseSpec:
    """The noise of the mean of ``frames`` frames: variance divided by ``frames``."""
    k = max(1, int(frames))
    return noise.model_copy(
        update={"read_noise_dn": noise.read_noise_dn / np.sqrt(k), "electrons_per_dn": noise.electrons_per_dn * k}
    )


def coding_scale(bundle: CalibrationBundle) -> float:
    """Largest ``σ_max(Pc)² σ_max(Qc)²`` over channels (DN²): the natural unit of τ."""
    sm = bundle.system_matrices
    best = 0.0
    for c in range(sm.channels):
        sp = np.linalg.norm(np.asarray(sm.Pc[c], np.float64), 2)
        sq = np.linalg.norm(np.asarray(sm.Qc[c], np.float64), 2)
        best = max(best, float(sp * sq) ** 2)
    return best


def choose_tau(
    profile: Profile,
    bundle: CalibrationBundle,
    scenes: list[np.ndarray],
    noise: NoiseSpec,
    decoder: str = DEFAULT_DECODER,
    seed: int = 0,
) -> tuple[float, dict[str, float]]:
    """τ maximising the mean PSNR on simulated measurements of ``scenes``.

    The measurements are ``bundle``'s own forward model plus Gaussian noise of ``noise``
    (use :func:`averaged_noise` for averaged frames), so the choice never looks at the
    validation frames it is later scored on.

    Returns
    -------
    (tau, table)
        The chosen τ (DN²) and ``{f"{tau:.3g}": mean PSNR dB}`` for every candidate.
    """
    rng = np.random.default_rng(seed)
    sm = bundle.system_matrices
    measured = []
    for x in scenes:
        y = sm.forward(x)
        var = noise.read_noise_dn**2 + np.maximum(y, 0) / noise.electrons_per_dn
        measured.append((y + rng.standard_normal(y.shape) * np.sqrt(var)).astype(np.float32))
    unit = coding_scale(bundle)
    table: dict[str, float] = {}
    best_tau, best = float("nan"), -np.inf
    for rel in TAU_GRID:
        tau = rel * unit
        dec = make_decoder(profile, bundle, decoder, tau=tau)
        value = float(np.mean([score("", dec.decode(y), x).psnr_db for y, x in zip(measured, scenes, strict=True)]))
        table[f"{tau:.3g}"] = value
        if value > best:
            best_tau, best = tau, value
    return best_tau, table
