"""``color_crosstalk``: ``signal_out[c] = Σ_k matrix[c][k]·signal_in[k]`` (diagonal fixed at 1)."""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.simulation.effects._spec import (
    DeviceProfile,
    EffectSpec,
    FitSpec,
    Params,
    ParamSpec,
    const,
)

BOUNDS = (-1.0, 1.0)
#: (row, column) of the six off-diagonal terms the diagnosis fits
OFF_DIAGONAL = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))


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


def _forward(signal: np.ndarray, params: Params, _profile: DeviceProfile) -> np.ndarray:
    if signal.shape[-1] != 3:  # one channel: nothing to mix
        return signal
    return apply(signal, params["matrix"])


def matrix_from_terms(v: np.ndarray) -> np.ndarray:
    """3×3 matrix with unit diagonal from its six off-diagonal terms (:data:`OFF_DIAGONAL`)."""
    m = np.eye(3)
    for (i, j), x in zip(OFF_DIAGONAL, v, strict=True):
        m[i, j] = x
    return m


def _to_params(v: np.ndarray, _p: DeviceProfile) -> dict[str, Any]:
    return {"matrix": [[round(float(x), 6) for x in row] for row in matrix_from_terms(v)]}


def _from_params(d: Params, _p: DeviceProfile) -> np.ndarray:
    m = np.asarray(d["matrix"], np.float64)
    return np.array([m[i, j] for i, j in OFF_DIAGONAL])


def describe(params: Params, _p: DeviceProfile) -> str:
    """The finding in words."""
    m = np.asarray(params["matrix"], float)
    off = m - np.diag(np.diag(m))
    i, j = np.unravel_index(int(np.argmax(np.abs(off))), off.shape)
    ch = "RGB"
    return (
        f"The colour channels leak into each other (largest: {off[i, j]:+.1%} of {ch[j]} appears "
        f"in {ch[i]}); the model assumed pure channels."
    )


SPEC = EffectSpec(
    name="color_crosstalk",
    stage="signal",
    order=10,
    description="each colour channel picks up a fraction of the other channels' light",
    params={
        "matrix": ParamSpec(
            "1", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], BOUNDS,
            "3×3 mixing matrix, rows = output channel; diagonal fixed at 1", shape=(3, 3),
        )
    },
    forward=_forward,
    validate=lambda params: check_diagonal(params["matrix"]),
    describe=describe,
    fit=FitSpec(
        "post", tuple(f"matrix[{i}][{j}]" for i, j in OFF_DIAGONAL), const(*([0.0] * 6)),
        const(*([0.03] * 6)), _to_params, _from_params,
        bounds=lambda _p: (np.full(6, BOUNDS[0]), np.full(6, BOUNDS[1])), signed=(True,) * 6,
    ),
)
