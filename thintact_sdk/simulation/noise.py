"""Sensor noise model of CONTRACTS §4, in digital numbers (DN).

``DN = round(black + Poisson(e·signal)/e + N(0, read²))`` clipped to ``[0, saturation]``,
with ``e = electrons_per_dn`` photo-electrons per DN and ``signal`` the expected DN above
black.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.formats.profiles import NoiseSpec

QUANTISATION_VARIANCE_DN2 = 1.0 / 12.0
"""Variance of rounding to integers (uniform over one DN)."""

MAX_POISSON_ELECTRONS = 1e18
"""Expected photo-electrons are capped here before the Poisson draw (numpy's limit is about
9.2e18). Far above any saturation level, so the clipped output is unchanged; it only keeps an
absurd gain (``simulate --gain 1e20``) from failing inside numpy."""


def signal_to_dn(
    signal_dn: np.ndarray,
    noise: NoiseSpec,
    rng: np.random.Generator | None = None,
    *,
    saturation_dn: float | None = None,
) -> np.ndarray:
    """Expected signal → raw DN.

    Parameters
    ----------
    signal_dn
        Expected signal in DN above black (any shape, e.g. ``R × S × C``); negative values
        are treated as 0 photo-electrons.
    noise
        The profile's noise section.
    rng
        Random generator; ``None`` gives the noiseless expected DN (not rounded).
    saturation_dn
        Clip level (absolute DN) when lower than ``noise.saturation_dn`` (the
        ``saturation`` effect); ``None`` uses ``noise.saturation_dn``.

    Returns
    -------
    numpy.ndarray
        float64 DN (black level included), same shape, clipped to ``[0, saturation]``.
    """
    sig = np.asarray(signal_dn, dtype=float)
    top = noise.saturation_dn if saturation_dn is None else min(saturation_dn, noise.saturation_dn)
    if rng is None:
        return np.clip(noise.black_level_dn + sig, 0.0, top)
    electrons = rng.poisson(np.clip(sig * noise.electrons_per_dn, 0.0, MAX_POISSON_ELECTRONS))
    dn = noise.black_level_dn + electrons / noise.electrons_per_dn
    if noise.read_noise_dn > 0:
        dn = dn + rng.normal(0.0, noise.read_noise_dn, size=sig.shape)
    return np.clip(np.round(dn), 0.0, top)


def default_white_level_dn(noise: NoiseSpec) -> float:
    """DN above black of a fully white display pixel when nothing says otherwise: 60 % of the
    range between black level and saturation (the virtual camera's default exposure level)."""
    return 0.6 * (noise.saturation_dn - noise.black_level_dn)


def signal_variance_dn(signal_dn: np.ndarray | float, noise: NoiseSpec, frames: int = 1) -> np.ndarray:
    """Variance (DN²) of the mean of ``frames`` frames at ``signal_dn`` DN *above black*:
    ``(max(signal, 0)/electrons_per_dn + read_noise²) / frames`` (shot and read noise, the
    Gaussian approximation used to draw simulated noise; no rounding term)."""
    shot = np.maximum(np.asarray(signal_dn, dtype=float), 0.0) / noise.electrons_per_dn
    return (shot + noise.read_noise_dn**2) / frames


def noise_variance_dn(predicted_dn: np.ndarray, noise: NoiseSpec) -> np.ndarray:
    """Variance (DN²) of the noise model at predicted DN values (black level included).

    ``σ² = max(predicted - black, 0)/electrons_per_dn + read_noise² + 1/12`` (shot noise,
    read noise, rounding), the σ² of CONTRACTS §6's χ².
    """
    pred = np.asarray(predicted_dn, dtype=float)
    return signal_variance_dn(pred - noise.black_level_dn, noise) + QUANTISATION_VARIANCE_DN2
