"""Reconstruct validation frames with a calibration and score them (PSNR, SSIM); choose τ.

Reconstruction goes through the registry's decoders (by default the first that declares the
trait ``calibration-candidate``: :func:`default_decoder`), so the figures are what a user of the
bundle gets. Which decoders the calibration compares, where each keeps its τ and which take a
scene prior come from their declared traits (:data:`thintact_sdk.hookspecs.TRAITS`), never from
their names.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from thintact_sdk.device.registry import get_registry
from thintact_sdk.errors import CalibrationError, InvalidValueError
from thintact_sdk.formats.profiles import NoiseSpec, Profile
from thintact_sdk.hookspecs import trait_value
from thintact_sdk.interfaces import Decoder
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.filter_training import scene_for_channels
from thintact_sdk.reconstruction.metrics import psnr, ssim
from thintact_sdk.reconstruction.tau_sweep import sweep_tau
from thintact_sdk.reconstruction.tikhonov import TikhonovSolver
from thintact_sdk.simulation.noise import signal_variance_dn

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
    saturated_fraction
        Fraction of the measurement's pixels at saturation (a saturated frame cannot be
        reconstructed faithfully: lower the exposure or the display brightness).
    """

    label: str
    psnr_db: float
    ssim: float
    estimate: np.ndarray
    truth: np.ndarray
    saturated_fraction: float = 0.0


def calibration_decoders() -> list[str]:
    """The decoders the calibration compares when none is imposed: those declaring the trait
    ``calibration-candidate``, in registry order (the core's first)."""
    return [c.name for c in get_registry().with_trait("decoder", "calibration-candidate")]


def default_decoder() -> str:
    """The calibration's decoder when none is named: the first of :func:`calibration_decoders`.

    Raises
    ------
    CalibrationError
        No registered decoder declares ``calibration-candidate``.
    """
    names = calibration_decoders()
    if not names:
        raise CalibrationError("no registered decoder declares the trait 'calibration-candidate'; "
                               "`thintact plugins` lists the decoders")
    return names[0]


def tau_key(name: str) -> str:
    """The ``calibration.json`` field holding decoder ``name``'s τ: its trait ``tau-key=FIELD``,
    else ``tau``."""
    return trait_value(get_registry().get("decoder", name).traits, "tau-key") or "tau"


def takes_scene_prior(name: str) -> bool:
    """Whether decoder ``name`` declares the trait ``scene-prior`` (its prior is cross-validated
    with τ and stored under ``calibration.json`` → ``scene_prior`` → ``name``)."""
    return "scene-prior" in get_registry().get("decoder", name).traits


def needs_joint_filter(name: str) -> bool:
    """Whether decoder ``name`` declares the trait ``joint-filter`` (it needs the bundle's
    trained joint filter)."""
    return "joint-filter" in get_registry().get("decoder", name).traits


def make_decoder(
    profile: Profile, bundle: CalibrationBundle, name: str | None = None, **settings: Any
) -> Decoder:
    """Build decoder ``name`` (default: :func:`default_decoder`) on ``bundle`` (settings such
    as ``tau`` are passed through)."""
    decoder = get_registry().create("decoder", name or default_decoder(), profile, {"bundle": bundle, **settings})
    return decoder  # type: ignore[no-any-return]


def _displayed(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``estimate`` clipped to [0, 1] (as displayed, ``N × M × C`` float32) and ``truth`` at its
    channel count (:func:`scene_for_channels`)."""
    est = np.clip(np.asarray(estimate, np.float32), 0.0, 1.0)
    if est.ndim == 2:
        est = est[..., None]
    return est, scene_for_channels(np.asarray(truth, np.float32), est.shape[2])


def score(label: str, estimate: np.ndarray, truth: np.ndarray) -> ValidationResult:
    """PSNR and SSIM of ``estimate`` against ``truth`` (clipped to [0, 1] first, as displayed).

    ``truth`` is brought to the estimate's channel count first (:func:`scene_for_channels`:
    a monochrome device is scored against the mean of the displayed channels).
    """
    est, tru = _displayed(estimate, truth)
    return ValidationResult(label, psnr(est, tru), ssim(est, tru), est, tru)


def score_psnr(estimate: np.ndarray, truth: np.ndarray) -> float:
    """:func:`score`'s PSNR (dB) alone, without its SSIM: for the many estimates a τ or decoder
    search scores and discards (the same figure, computed the same way)."""
    return psnr(*_displayed(estimate, truth))


def averaged_noise(noise: NoiseSpec, frames: int) -> NoiseSpec:
    """The noise of the mean of ``frames`` frames: variance divided by ``frames``."""
    k = max(1, int(frames))
    return noise.model_copy(
        update={"read_noise_dn": noise.read_noise_dn / np.sqrt(k), "electrons_per_dn": noise.electrons_per_dn * k}
    )


def choose_tau(
    bundle: CalibrationBundle,
    scenes: list[np.ndarray],
    noise: NoiseSpec,
    seed: int = 0,
) -> tuple[float, dict[str, float]]:
    """τ maximising the mean PSNR on simulated measurements of ``scenes``.

    The measurements are ``bundle``'s own forward model plus Gaussian noise of ``noise``
    (use :func:`averaged_noise` for averaged frames), so the choice never looks at the
    validation frames it is later scored on. Each candidate is the non-iterative decoder's
    math (joint filter, then the closed-form Tikhonov of :class:`TikhonovSolver`), with the
    SVDs computed once.

    Returns
    -------
    (tau, table)
        The chosen τ (DN²) and ``{f"{tau:.3g}": mean PSNR dB}`` for every candidate.
    """
    if bundle.filter is None:
        raise InvalidValueError("choose_tau needs a bundle with a trained filter")
    rng = np.random.default_rng(seed)
    sm = bundle.system_matrices
    coding = []
    scenes = [scene_for_channels(x, sm.channels) for x in scenes]
    for x in scenes:
        y = sm.forward(x)
        var = signal_variance_dn(y, noise)
        y = y + rng.standard_normal(y.shape) * np.sqrt(var)
        coding.append(np.asarray(bundle.filter.coding_component(y), np.float64))
    solvers = [TikhonovSolver(sm.Pc[c], sm.Qc[c], 1.0) for c in range(sm.channels)]
    spectra = [np.outer(s.singular_values_p**2, s.singular_values_q**2) for s in solvers]
    unit = max(float(sp.max()) for sp in spectra)
    def mean_psnr(tau: float) -> float:
        for solver, spec in zip(solvers, spectra, strict=True):
            solver.inv_denom = 1.0 / (spec + tau)
        values = []
        for yc, x in zip(coding, scenes, strict=True):
            est = np.stack([solvers[c].solve(yc[..., c]) for c in range(sm.channels)], axis=-1)
            values.append(score_psnr(est, x))
        return float(np.mean(values))

    sweep = sweep_tau([rel * unit for rel in TAU_GRID], mean_psnr)
    return sweep.tau, {f"{tau:.3g}": value for tau, value in sweep.scores}
