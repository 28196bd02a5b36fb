"""The T2S system matrices of one channel, as the slit-scan solver and its gauge fixing share them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ChannelMatrices:
    """T2S system matrices of one channel, DN (above dark) per display unit per scene pixel.

    Attributes
    ----------
    Po, Pc
        ``R × N`` float64.
    Qo, Qc
        ``S × M`` float64.
    """

    Po: np.ndarray
    Qo: np.ndarray
    Pc: np.ndarray
    Qc: np.ndarray

    def forward(self, scene: np.ndarray) -> np.ndarray:
        """``Po X Qoᵀ + Pc X Qcᵀ`` for an ``N × M`` scene → ``R × S``."""
        return self.Po @ scene @ self.Qo.T + self.Pc @ scene @ self.Qc.T

    def copy(self) -> ChannelMatrices:
        return ChannelMatrices(self.Po.copy(), self.Qo.copy(), self.Pc.copy(), self.Qc.copy())
