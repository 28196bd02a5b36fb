"""What the closed-form decoders share: shape checks and the two entry points, ``decode``
(signal above black) and ``decode_raw`` (raw binned DN, the black level folded into the solve as a
precomputed constant, so the only per-pixel work before the products is one conversion)."""

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

    sensor_shape: tuple[int, int]
    channels: int
    xp: Any

    def _solve(self, y_cf: Any, black_dn: float = 0.0) -> np.ndarray:
        raise NotImplementedError

    def _check(self, signal: np.ndarray) -> None:
        check_measurement_shape(signal, self.sensor_shape, self.channels)

    def decode(self, signal: np.ndarray) -> np.ndarray:
        """Reconstruct ``N × M × C`` float32 (display units) from ``R × S × C`` DN above black."""
        self._check(signal)
        return self._solve(self.xp.channels_first(signal, gemm=True))

    def decode_raw(self, raw: np.ndarray, black_level_dn: float) -> np.ndarray:
        """Reconstruct from raw binned DN (``R × S × C``, e.g. uint16, black level included)."""
        self._check(raw)
        return self._solve(self.xp.channels_first(raw, gemm=True), float(black_level_dn))
