"""Synthetic T2S systems and slit scans, for tests and benchmarks of the calibration.

The matrices follow the 1-D geometry of a separable mask (CONTRACTS §1, §4): scene pixel n
at ``s``, sensor pixel r at ``u``, the ray crosses the mask at ``m = u + (s − u)·d/H``; the
open term is ``env/2`` and the coding term ``env·φ(m)/2`` with ``env`` a smooth
cos⁴-like fall-off. Real slit images are made from them with any per-frame gain, offset and
Poisson/read noise a test wants.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.calibration.solver import ChannelMatrices


def one_axis(
    n_sensor: int,
    n_scene: int,
    phi: np.ndarray,
    sensor_pitch_um: float = 10.0,
    scene_pitch_um: float = 31.5,
    feature_um: float = 20.0,
    z_mm: float = 4.8,
    d_mm: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Open and coding matrices (``n_sensor × n_scene``) of one axis.

    Returns
    -------
    (open, coding)
        float64; ``open ≥ 0`` smooth, ``coding`` = ``open``·φ(m) (±).
    """
    h_um = (z_mm + d_mm) * 1000.0
    u = (np.arange(n_sensor) - (n_sensor - 1) / 2) * sensor_pitch_um
    s = (np.arange(n_scene) - (n_scene - 1) / 2) * scene_pitch_um
    du = s[None, :] - u[:, None]
    env = (h_um**2 / (h_um**2 + du**2)) ** 2 * 0.5
    m = u[:, None] + du * (d_mm * 1000.0 / h_um)
    k = len(phi)
    j = np.floor(m / feature_um + k / 2).astype(int)
    inside = (j >= 0) & (j < k)
    code = np.where(inside, np.asarray(phi, float)[np.clip(j, 0, k - 1)], 0.0)
    return env * inside, env * code


def system(
    rows: int = 64,
    cols: int = 80,
    scene_rows: int = 24,
    scene_cols: int = 32,
    k: int = 127,
    seed: int = 0,
    gain_dn: float = 40.0,
) -> ChannelMatrices:
    """A random-mask T2S system; ``gain_dn`` scales it to DN per display unit."""
    rng = np.random.default_rng(seed)
    phi = rng.choice([-1.0, 1.0], size=k)
    po, pc = one_axis(rows, scene_rows, phi)
    qo, qc = one_axis(cols, scene_cols, phi)
    g = np.sqrt(gain_dn)
    return ChannelMatrices(po * g, qo * g, pc * g, qc * g)


def slit_images(
    mats: ChannelMatrices,
    noise_dn: float = 0.0,
    electrons_per_dn: float | None = None,
    gains: np.ndarray | None = None,
    offset_dn: np.ndarray | float = 0.0,
    seed: int = 1,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Horizontal and vertical slit images ``R × S`` (DN) of ``mats``.

    Parameters
    ----------
    noise_dn
        Gaussian read noise σ in DN.
    electrons_per_dn
        If given, Poisson shot noise on the signal.
    gains
        Optional per-frame gain (length N + M), e.g. exposure differences.
    offset_dn
        Added to every image (a dark level that the caller may or may not remove).
    """
    n, m = mats.Po.shape[1], mats.Qo.shape[1]
    rng = np.random.default_rng(seed)
    qo1, qc1 = mats.Qo.sum(1), mats.Qc.sum(1)
    po1, pc1 = mats.Po.sum(1), mats.Pc.sum(1)
    out_h: list[np.ndarray] = []
    out_v: list[np.ndarray] = []
    for i in range(n + m):
        if i < n:
            y = np.outer(mats.Po[:, i], qo1) + np.outer(mats.Pc[:, i], qc1)
        else:
            j = i - n
            y = np.outer(po1, mats.Qo[:, j]) + np.outer(pc1, mats.Qc[:, j])
        if gains is not None:
            y = y * gains[i]
        if electrons_per_dn is not None:
            y = rng.poisson(np.clip(y, 0, None) * electrons_per_dn) / electrons_per_dn
        y = y + offset_dn + rng.normal(0.0, noise_dn, y.shape) if noise_dn > 0 else y + offset_dn
        (out_h if i < n else out_v).append(np.asarray(y, dtype=np.float64))
    return out_h, out_v
