"""What the closed-form decoders share: shape checks and the one entry point ``decode(frame,
black_level_dn)`` of a decoder declaring ``input = "raw"``: ``R × S × C`` DN with the black level
(a signal above black with ``black_level_dn`` 0), the black level folded into the solve as a
precomputed constant, so the only per-pixel work before the products is one conversion."""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.interfaces import Decoder
from thintact_sdk.reconstruction.decoders.shapes import check_measurement_shape


class ClosedFormDecoder(Decoder):
    """Base of decoders whose ``_solve(y_cf, black_dn)`` takes channel-first GEMM-precision data.

    Subclasses set ``sensor_shape`` ``(R, S)``, ``channels`` and ``xp`` (the array backend) and
    implement ``_solve``.
    """

    input = "raw"
    sensor_shape: tuple[int, int]
    channels: int
    xp: Any

    def _solve(self, y_cf: Any, black_dn: float = 0.0) -> np.ndarray:
        raise NotImplementedError

    def _check(self, signal: np.ndarray) -> None:
        check_measurement_shape(signal, self.sensor_shape, self.channels)

    def decode(self, frame: np.ndarray, black_level_dn: float = 0.0) -> np.ndarray:
        """Reconstruct ``N × M × C`` float32 (display units) from ``R × S × C`` DN (float or
        e.g. uint16) holding the black level ``black_level_dn`` DN (0: a signal above black)."""
        self._check(frame)
        return self._solve(self.xp.channels_first(frame, gemm=True), float(black_level_dn))
