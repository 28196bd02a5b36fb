"""A separable Gaussian prior on the scene: generalised Tikhonov with DCT-domain weights.

Plain Tikhonov penalises ``τ‖X‖²_F``: every spatial frequency of the scene is shrunk alike, so
one τ is a compromise between scenes that want little smoothing (checkers, USAF) and scenes
that want a lot (uniform fields, white). The prior here penalises ``τ‖W_L X W_Rᵀ‖²_F`` with

    W = diag(w) D,   w_k = (1 + k / k0)^α,   k = 0 … n−1

per axis (``D`` the orthonormal DCT-II): high DCT frequencies cost ``w`` times more than the
mean, i.e. the scene is a Gaussian field whose DCT coefficient ``(i, j)`` has standard
deviation ``∝ 1 / (w_i w_j)``. ``α = 0`` is plain Tikhonov.

The problem stays a T2S Tikhonov problem after the change of variable ``Z = W_L X W_Rᵀ``:
``P X Qᵀ = (P W_L⁻¹) Z (Q W_R⁻¹)ᵀ`` for every term, so any exact Tikhonov solver of
``min ‖Σ P' Z Q'ᵀ − Y‖² + τ‖Z‖²`` gives ``X = W_L⁻¹ Z W_R⁻ᵀ`` exactly
(:meth:`ScenePrior.transform`, :meth:`ScenePrior.inverse`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from thintact_sdk.errors import CalibrationError
from thintact_sdk.reconstruction.dct import dct_matrix
from thintact_sdk.reconstruction.t2s import SystemMatrices

PRIOR_KIND = "dct-power"
"""``kind`` of the JSON form (the only one so far)."""


@dataclass(frozen=True)
class ScenePrior:
    """DCT-domain weights ``(1 + k/k0)^α`` on both scene axes.

    Attributes
    ----------
    alpha
        Exponent α ≥ 0 (0: plain Tikhonov).
    k0
        Knee of the weights, in DCT index units (> 0): ``w`` doubles (for α = 1) at ``k = k0``.
    """

    alpha: float
    k0: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.alpha) and self.alpha >= 0):
            raise CalibrationError(f"scene prior: alpha {self.alpha!r} must be a finite number >= 0")
        if not (np.isfinite(self.k0) and self.k0 > 0):
            raise CalibrationError(f"scene prior: k0 {self.k0!r} must be a finite number > 0")

    @property
    def is_plain(self) -> bool:
        """True when the prior is plain Tikhonov (α = 0)."""
        return self.alpha == 0.0

    def weights(self, n: int) -> np.ndarray:
        """``w_k = (1 + k/k0)^α`` for ``k = 0 … n−1`` (float64)."""
        return (1.0 + np.arange(n, dtype=np.float64) / self.k0) ** self.alpha

    def inverse_weight(self, n: int) -> np.ndarray:
        """``W⁻¹ = Dᵀ diag(1/w)`` (``n × n`` float64) for an axis of ``n`` scene pixels."""
        return dct_matrix(n).T / self.weights(n)

    def weight(self, n: int) -> np.ndarray:
        """``W = diag(w) D`` (``n × n`` float64)."""
        return self.weights(n)[:, None] * dct_matrix(n)

    def transform(self, sm: SystemMatrices) -> SystemMatrices:
        """The matrices of the variable ``Z = W_L X W_Rᵀ``: every term's ``P W_L⁻¹``, ``Q W_R⁻¹``."""
        n, m = sm.scene_shape
        left, right = self.inverse_weight(n), self.inverse_weight(m)
        return SystemMatrices(np.asarray(sm.Po, np.float64) @ left, np.asarray(sm.Qo, np.float64) @ right,
                              np.asarray(sm.Pc, np.float64) @ left, np.asarray(sm.Qc, np.float64) @ right,
                              dict(sm.meta))

    def inverse(self, z: np.ndarray) -> np.ndarray:
        """``X = W_L⁻¹ Z W_R⁻ᵀ`` for ``Z`` of shape ``N × M`` or ``N × M × C``."""
        z = np.asarray(z, np.float64)
        left, right = self.inverse_weight(z.shape[0]), self.inverse_weight(z.shape[1])
        if z.ndim == 2:
            return np.asarray(left @ z @ right.T)
        return np.einsum("ni,ijc,mj->nmc", left, z, right)

    def to_json(self) -> dict[str, Any]:
        """``{"kind": "dct-power", "alpha": α, "k0": k0}``."""
        return {"kind": PRIOR_KIND, "alpha": float(self.alpha), "k0": float(self.k0)}

    @classmethod
    def from_json(cls, d: Any, where: str = "scene prior") -> ScenePrior:
        """Parse :meth:`to_json`'s form; a :class:`CalibrationError` naming ``where`` otherwise."""
        if not isinstance(d, dict) or d.get("kind") != PRIOR_KIND:
            raise CalibrationError(f"{where}: {d!r} is not a scene prior: it must be "
                                   f'{{"kind": "{PRIOR_KIND}", "alpha": >= 0, "k0": > 0}}')
        try:
            alpha, k0 = float(d["alpha"]), float(d["k0"])
        except (KeyError, TypeError, ValueError):
            raise CalibrationError(f"{where}: {d!r} needs numeric 'alpha' and 'k0'") from None
        try:
            return cls(alpha, k0)
        except CalibrationError as err:
            raise CalibrationError(f"{where}: {err}") from None
