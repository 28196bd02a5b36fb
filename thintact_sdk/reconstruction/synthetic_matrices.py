"""Synthetic T2S system matrices with known structure, for tests and for checking decoders.

``frequency_split_matrices`` builds matrices whose open component lives exactly in the
lowest ``k_rows × k_cols`` DCT frequencies of the measurement and whose coding component has
no energy there, so a joint filter with ``Φf = 1`` on that block (0 elsewhere) and ``Φs = 1``
separates them exactly and every decoder can recover the scene exactly from noiseless data.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.reconstruction.dct import dct_matrix
from thintact_sdk.reconstruction.joint_filter import JointFilter
from thintact_sdk.reconstruction.t2s import SystemMatrices


def frequency_split_matrices(
    sensor_shape: tuple[int, int],
    scene_shape: tuple[int, int],
    low_block: tuple[int, int],
    channels: int = 3,
    seed: int = 0,
    gain_dn: float = 100.0,
) -> tuple[SystemMatrices, JointFilter]:
    """Random T2S matrices whose open/coding parts are split by DCT frequency.

    Parameters
    ----------
    sensor_shape
        ``(R, S)``; needs ``R − k_rows ≥ N`` and ``S − k_cols ≥ M``.
    scene_shape
        ``(N, M)``.
    low_block
        ``(k_rows, k_cols)``: the DCT block that holds the open component.
    gain_dn
        Overall scale of the signal (DN per display unit, order of magnitude).

    Returns
    -------
    SystemMatrices, JointFilter
        The matrices (``C`` channels with different gains) and the exact separating filter.
    """
    (r, s), (n, m), (kr, ks) = sensor_shape, scene_shape, low_block
    if r - kr < n or s - ks < m:
        raise ValueError("need R − k_rows ≥ N and S − k_cols ≥ M for exact recovery")
    rng = np.random.default_rng(seed)
    dr, ds = dct_matrix(r), dct_matrix(s)
    mats: dict[str, list[np.ndarray]] = {"Po": [], "Qo": [], "Pc": [], "Qc": []}
    for c in range(channels):
        g = np.sqrt(gain_dn * (1.0 + 0.2 * c) / np.sqrt(n * m))
        mats["Po"].append(g * dr[:kr].T @ rng.standard_normal((kr, n)))
        mats["Qo"].append(g * ds[:ks].T @ rng.standard_normal((ks, m)))
        mats["Pc"].append(g * dr[kr:].T @ rng.standard_normal((r - kr, n)) / np.sqrt(r / n))
        mats["Qc"].append(g * ds[ks:].T @ rng.standard_normal((s - ks, m)) / np.sqrt(s / m))
    sm = SystemMatrices(
        np.stack(mats["Po"]), np.stack(mats["Qo"]), np.stack(mats["Pc"]), np.stack(mats["Qc"]),
        {"source": "synthetic-frequency-split", "low_block": [kr, ks], "seed": seed},
    )
    phi_f = np.zeros((channels, r, s))
    phi_f[:, :kr, :ks] = 1.0
    return sm, JointFilter(phi_f, np.ones((channels, r, s)), {"source": "exact"})
