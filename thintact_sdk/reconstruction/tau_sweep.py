"""Choosing the Tikhonov weight τ by a sweep: score every candidate, keep the best.

One loop for every τ choice of the SDK (virtual calibration, the calibration wizard's
simulated validation, the reconstruction benchmark); each caller decides what it scores on
(never the scenes it is later judged on) and how it reports the table.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from thintact_sdk.interfaces import TunableDecoder
from thintact_sdk.reconstruction.metrics import psnr


@dataclass(frozen=True)
class TauSweep:
    """The outcome of a sweep.

    Attributes
    ----------
    tau
        The best candidate (DN²); the first of equals wins.
    score
        Its score (e.g. mean PSNR, dB).
    scores
        ``(tau, score)`` for every candidate, in sweep order.
    """

    tau: float
    score: float
    scores: list[tuple[float, float]]


def sweep_tau(taus: Sequence[float], mean_score: Callable[[float], float]) -> TauSweep:
    """Score every candidate τ with ``mean_score(tau)`` (higher is better) and keep the best.

    Raises
    ------
    ValueError
        With no candidate (a programming error: every caller has a fixed grid).
    """
    if not taus:
        raise ValueError("sweep_tau needs at least one candidate")
    scores = [(float(t), float(mean_score(float(t)))) for t in taus]
    best = max(range(len(scores)), key=lambda i: (scores[i][1], -i))
    return TauSweep(scores[best][0], scores[best][1], scores)


def mean_psnr_db(decode: Callable[[np.ndarray], np.ndarray], measurements: Sequence[np.ndarray],
                 scenes: Sequence[np.ndarray]) -> float:
    """Mean PSNR (dB) of ``decode`` clipped to [0, 1] over measurement/scene pairs."""
    return float(np.mean([psnr(np.clip(decode(y), 0.0, 1.0), x)
                          for y, x in zip(measurements, scenes, strict=True)]))


def tune_decoder_tau(decoder: TunableDecoder, taus: Sequence[float],
                     measurements: Sequence[np.ndarray], scenes: Sequence[np.ndarray]) -> TauSweep:
    """The τ among ``taus`` maximising ``decoder``'s mean PSNR on the pairs; the decoder is left
    set to it.

    Parameters
    ----------
    decoder
        A decoder whose τ changes without rebuilding it.
    taus
        Candidates, DN².
    measurements, scenes
        ``R × S × C`` signals (DN above black) and their ``N × M × C`` scenes.
    """
    def score(tau: float) -> float:
        decoder.set_tau(tau)
        return mean_psnr_db(decoder.decode, measurements, scenes)

    result = sweep_tau(taus, score)
    decoder.set_tau(result.tau)
    return result
