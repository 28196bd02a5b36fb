"""FlatCam closed-form baseline (Asif et al. 2016): coding term only, no joint filter.

FlatCam models the measurement as ``Pc X Qcᵀ`` after removing the open (all-ones) part of the
mask, which for a distant scene is constant along sensor rows and columns. It removes that part
by subtracting row and column means (double centring ``C_R Y C_S``, ``C_n = I − 11ᵀ/n``) and
solves the closed-form Tikhonov problem with the centred matrices ``C_R Pc`` and ``C_S Qc``.
The centring of Y is implicit: the left singular vectors of ``C_R Pc`` are orthogonal to 1.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.interfaces import Decoder
from thintact_sdk.reconstruction.decoders.backend import ArrayBackend, synthesis_macs
from thintact_sdk.reconstruction.decoders.modes import DEFAULT_MODE_RTOL, kept_mode_counts
from thintact_sdk.reconstruction.decoders.shapes import check_measurement_shape
from thintact_sdk.reconstruction.t2s import SystemMatrices
from thintact_sdk.reconstruction.tikhonov import TikhonovSolver


def _centred(a: np.ndarray) -> np.ndarray:
    return a - a.mean(axis=0, keepdims=True)


class FlatCamDecoder(Decoder):
    """Closed-form FlatCam reconstruction with row/column-mean removal.

    Parameters
    ----------
    system_matrices
        T2S matrices; only ``Pc``, ``Qc`` are used.
    tau
        Tikhonov weight τ.
    backend
        :class:`ArrayBackend` (default numpy float32).
    mode_rtol
        Tikhonov modes whose filter factor stays below this are not computed
        (:func:`~thintact_sdk.reconstruction.decoders.modes.kept_mode_counts`).
    """

    name = "flatcam"

    def __init__(self, system_matrices: SystemMatrices, tau: float, backend: ArrayBackend | None = None,
                 mode_rtol: float = DEFAULT_MODE_RTOL) -> None:
        self.xp = backend or ArrayBackend("numpy")
        sm = system_matrices
        self.channels = sm.channels
        self.sensor_shape = sm.sensor_shape
        self.scene_shape = sm.scene_shape
        solvers = [
            TikhonovSolver(_centred(sm.Pc[c].astype(np.float64)), _centred(sm.Qc[c].astype(np.float64)), tau)
            for c in range(sm.channels)
        ]
        kp, kq = kept_mode_counts(np.stack([s.singular_values_p for s in solvers]),
                                  np.stack([s.singular_values_q for s in solvers]), tau, mode_rtol)
        self.kept_modes = (kp, kq)
        xp = self.xp
        self._left = xp.asarray(np.stack([s.left[:kp] for s in solvers]), gemm=True)
        self._right = xp.asarray(np.stack([s.right[:, :kq] for s in solvers]), gemm=True)
        self._inv_denom = xp.asarray(np.stack([s.inv_denom[:kp, :kq] for s in solvers]))
        self._vp = xp.asarray(np.stack([s.vp[:, :kp] for s in solvers]), gemm=True)
        self._vqt = xp.asarray(np.stack([s.vqt[:kq] for s in solvers]), gemm=True)

    def gemm_flops(self) -> int:
        """Floating-point operations of the matrix products of one frame, all channels."""
        (r, s), (n, m), (kp, kq) = self.sensor_shape, self.scene_shape, self.kept_modes
        return 2 * self.channels * (kp * r * s + kp * s * kq + synthesis_macs(n, kp, kq, m))

    def decode(self, frame: np.ndarray, black_level_dn: float = 0.0) -> np.ndarray:
        """Reconstruct ``N × M × C`` float32 from an ``R × S × C`` signal, DN above black
        (``input = "signal"``: ``black_level_dn`` is subtracted first where not 0)."""
        check_measurement_shape(frame, self.sensor_shape, self.channels)
        signal = frame if not black_level_dn else np.asarray(frame, np.float32) - np.float32(black_level_dn)
        xp = self.xp
        y = xp.channels_first(signal, gemm=True)
        core = xp.cast(self._left @ y @ self._right, gemm=False) * self._inv_denom
        return xp.synthesise(self._vp, core, self._vqt)
