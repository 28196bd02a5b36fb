"""Compare mask designs on one device: white-scene uniformity, PSNR, SSIM and fitness.

Also compares direct generation with the exact physics (the simulator's two-term fit).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from thintact_masks.fitness import Evaluation, FitnessEvaluator, FitnessSettings
from thintact_sdk.algorithms import direct_system_matrices
from thintact_sdk.interfaces import Mask
from thintact_sdk.plugin_support import Profile, blas_threads


@dataclass
class MaskScore:
    """Reconstruction quality of one mask on one device (fitness simulation).

    Attributes
    ----------
    name
        Label of the mask.
    fitness
        The paper's fitness.
    uniformity_white
        ``1 − std/mean`` of the white reconstruction (1 is perfectly uniform).
    psnr_white_db, psnr_usaf_db
        PSNR (dB, peak 1) of the white and USAF reconstructions.
    ssim_white, ssim_usaf
        SSIM of the same.
    """

    name: str
    fitness: float
    uniformity_white: float
    psnr_white_db: float
    psnr_usaf_db: float
    ssim_white: float
    ssim_usaf: float

    def as_dict(self) -> dict[str, float | str]:
        return dict(self.__dict__)


def _score_each(profile: Profile, masks: dict[str, Mask], settings: FitnessSettings | None,
                evaluate: Callable[[FitnessEvaluator, Mask], Evaluation]) -> list[MaskScore]:
    """Score every mask with ``evaluate`` (one evaluator per K, single-threaded BLAS)."""
    out = []
    evaluators: dict[int, FitnessEvaluator] = {}
    with blas_threads(1):
        for name, mask in masks.items():
            ev = evaluators.get(mask.K)
            if ev is None:
                ev = evaluators[mask.K] = FitnessEvaluator(profile, mask.K, settings)
            e = evaluate(ev, mask)
            p = e.parts
            out.append(MaskScore(name, e.fitness, p["uniformity_white"], p["psnr_white"],
                                 p["psnr_usaf"], p["ssim_white"], p["ssim_usaf"]))
    return out


def score_masks(profile: Profile, masks: dict[str, Mask],
                settings: FitnessSettings | None = None) -> list[MaskScore]:
    """Score every mask on ``profile`` (each with its own K; φ_rows is taken as φ)."""
    return _score_each(profile, masks, settings, lambda ev, mask: ev.evaluate(np.asarray(mask.phi)))


def simulator_coding_matrices(profile: Profile, phi: np.ndarray,
                              channel: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``Pc``, ``Qc`` of φ on ``profile`` from the exact simulator (best rank-1 fit of its
    coding part), in the relative units of direct generation (white scene through a fully
    open mask = 1 at the sensor centre, from the fitted open part)."""
    from thintact_sdk.algorithms import Simulator, SystemMatrices

    phi_list = [int(v) for v in np.asarray(phi)]
    prof = profile.model_copy(update={"mask": profile.mask.model_copy(
        update={"phi": phi_list, "phi_rows": None})}, deep=True)
    po, qo, pc, qc = SystemMatrices.two_term_fit(Simulator(prof), channels=[channel]).channel(0)

    def centre(v: np.ndarray) -> float:
        n = v.shape[0]
        return float(v[(n - 1) // 2 : n // 2 + 1].mean())

    white_open = 2.0 * centre(po.sum(axis=1)) * centre(qo.sum(axis=1))
    s = 1.0 / np.sqrt(abs(white_open))
    return pc * s, qc * s


def score_masks_exact(profile: Profile, masks: dict[str, Mask],
                      settings: FitnessSettings | None = None) -> list[MaskScore]:
    """Like :func:`score_masks`, but with the coding matrices of the exact simulator instead
    of direct generation: checks that a design's advantage is not an artefact of the
    direct-generation approximation."""
    return _score_each(profile, masks, settings, lambda ev, mask: ev.evaluate_matrices(
        *simulator_coding_matrices(profile, np.asarray(mask.phi))))


def direct_vs_simulator(profile: Profile, d_stripe_px: float | None = None,
                        channel: int = 0) -> float:
    """Relative Frobenius difference of the direct-generation T2S operator from the
    simulator's best two-term fit, after the best overall scale (gain is a nuisance).

    Needs :class:`thintact_sdk.simulation.simulator.Simulator` and
    :meth:`thintact_sdk.reconstruction.t2s.SystemMatrices.two_term_fit`.
    """
    from thintact_sdk.algorithms import Simulator, SystemMatrices, kron_sum_norm2

    fit = SystemMatrices.two_term_fit(Simulator(profile), channels=[channel])
    po_f, qo_f, pc_f, qc_f = fit.channel(0)
    po, qo, pc, qc = direct_system_matrices(np.asarray(profile.mask.phi), profile, d_stripe_px,
                                            phi_rows=np.asarray(profile.mask.rows_vector))
    a = [(1.0, po, qo), (1.0, pc, qc)]
    b = [(1.0, po_f, qo_f), (1.0, pc_f, qc_f)]
    aa, bb = kron_sum_norm2(a), kron_sum_norm2(b)
    diff = kron_sum_norm2(a + [(-1.0, p, q) for _, p, q in b])
    ab = 0.5 * (aa + bb - diff)
    resid = max(bb - ab * ab / aa, 0.0)
    return float(np.sqrt(resid / bb))
