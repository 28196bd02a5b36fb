"""The frequency-spatial joint filter of the non-iterative decoder (paper §B).

``F(Y) = Φs ⊙ IDCT(Φf ⊙ DCT(Y))`` per channel (orthonormal 2-D DCT-II): it estimates the
open component ``Yo = Po X Qoᵀ`` of a measurement, so that ``Yc = Y − F(Y)`` is left for the
closed-form Tikhonov solve. Stored as ``filter.npz`` with ``phi_f`` and ``phi_s`` (``C × R × S``
float32 each) and a ``meta_json`` entry.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import CalibrationError, InvalidShapeError
from thintact_sdk.reconstruction.dct import SeparableDCT

FILTER_FORMAT = "thintact-joint-filter/1"


def joint_filter_open(phi_s: Any, phi_f: Any, y: Any, transform: SeparableDCT) -> Any:
    """``Φs ⊙ IDCT(Φf ⊙ DCT(Y))``: the joint filter's estimate of the open component, on any
    array backend (the one implementation; ``Φ`` broadcast against channel-first ``Y``).

    Parameters
    ----------
    phi_s, phi_f
        ``C × R × S`` (or ``R × S``) spatial and frequency weights, dimensionless.
    y
        ``... × C × R × S`` measurement signal, DN (channel-first).
    transform
        The DCT for this array type and sensor shape.
    """
    return phi_s * transform.inv(phi_f * transform.fwd(y))


@dataclass
class JointFilter:
    """Trained joint filter parameters.

    Parameters
    ----------
    phi_f
        ``C × R × S`` frequency-domain weights Φf (dimensionless, on DCT coefficients).
    phi_s
        ``C × R × S`` spatial-domain weights Φs (dimensionless, on sensor pixels).
    meta
        Training settings and figures (loss, steps, scenes).
    """

    phi_f: np.ndarray
    phi_s: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.phi_f = np.asarray(self.phi_f)
        self.phi_s = np.asarray(self.phi_s)
        if self.phi_f.ndim == 2:
            self.phi_f = self.phi_f[None]
        if self.phi_s.ndim == 2:
            self.phi_s = self.phi_s[None]
        if self.phi_f.shape != self.phi_s.shape or self.phi_f.ndim != 3:
            raise CalibrationError(
                f"filter Φf {self.phi_f.shape} and Φs {self.phi_s.shape} must both be C×R×S"
            )

    @property
    def channels(self) -> int:
        """Number of channels C."""
        return int(self.phi_f.shape[0])

    @property
    def sensor_shape(self) -> tuple[int, int]:
        """``(R, S)``."""
        return int(self.phi_f.shape[1]), int(self.phi_f.shape[2])

    def apply(self, signal: np.ndarray) -> np.ndarray:
        """Estimated open component ``F(Y)`` of ``signal`` (``R × S × C``, DN) → ``R × S × C``."""
        y = np.moveaxis(np.asarray(signal), -1, 0)
        if y.shape[1:] != self.sensor_shape:
            raise InvalidShapeError(f"signal must be {self.sensor_shape}×C, got {np.shape(signal)}")
        out = joint_filter_open(self.phi_s, self.phi_f, y, SeparableDCT(self.sensor_shape))
        return np.moveaxis(out, 0, -1)

    def coding_component(self, signal: np.ndarray) -> np.ndarray:
        """``Yc = Y − F(Y)`` (``R × S × C``, DN)."""
        return np.asarray(signal) - self.apply(signal)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write ``filter.npz`` (float32, compressed); returns the path."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        meta = {"format": FILTER_FORMAT, **self.meta}
        with open(p, "wb") as f:
            np.savez_compressed(
                f,
                phi_f=self.phi_f.astype(np.float32),
                phi_s=self.phi_s.astype(np.float32),
                meta_json=np.array(json.dumps(meta)),
            )
        return p

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> JointFilter:
        """Read a file written by :meth:`save`; raises CalibrationError when unusable."""
        from thintact_sdk.formats.bundle_npz import read_npz

        p = Path(path)
        arrays, meta = read_npz(p, "filter", ("phi_f", "phi_s"))
        meta.pop("format", None)
        try:
            return cls(arrays["phi_f"], arrays["phi_s"], meta)
        except CalibrationError as err:
            raise CalibrationError(f"{p}: {err}") from None
