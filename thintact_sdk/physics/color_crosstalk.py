"""``color_crosstalk``: ``signal_out[c] = Σ_k matrix[c][k]·signal_in[k]`` (diagonal fixed at 1)."""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="color_crosstalk",
    stage="signal",
    description="each colour channel picks up a fraction of the other channels' light",
    params={
        "matrix": ParamSpec(
            "1", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], (-1.0, 1.0),
            "3×3 mixing matrix, rows = output channel; diagonal fixed at 1", shape=(3, 3),
        )
    },
)


def check_diagonal(matrix: Any) -> None:
    """Raise unless the diagonal is 1 (the per-channel gain is a separate nuisance)."""
    diag = np.diag(np.asarray(matrix, float))
    if not np.allclose(diag, 1.0):
        raise ThinTactError(
            f"physics.color_crosstalk.matrix: the diagonal must be 1 (got {diag.tolist()}); "
            "per-channel scale is the free gain"
        )


def apply(signal: np.ndarray, matrix: Any) -> np.ndarray:
    """Mix the channels of ``F × R × S × 3`` signals."""
    m = np.asarray(matrix, float)
    if np.array_equal(m, np.eye(3)):
        return signal
    return np.einsum("frsk,ck->frsc", signal, m)
