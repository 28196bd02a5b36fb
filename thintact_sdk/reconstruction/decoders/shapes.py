"""The one measurement-shape check every decoder of this plugin makes."""

from __future__ import annotations

import numpy as np

from thintact_sdk.errors import InvalidShapeError


def check_measurement_shape(signal: np.ndarray, sensor_shape: tuple[int, int], channels: int) -> None:
    """Raise ValueError unless ``signal`` is ``R × S × C`` for the decoder's sensor."""
    want = (*sensor_shape, channels)
    if signal.shape != want:
        raise InvalidShapeError(f"measurement must be {want[0]}×{want[1]}×{want[2]}, got {signal.shape}")
