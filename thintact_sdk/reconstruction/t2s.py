"""Texas Two-Step (T2S) system matrices: ``Y = Po X Qoᵀ + Pc X Qcᵀ`` per channel (paper eq. 2).

:class:`SystemMatrices` holds the four matrices of every channel, shaped ``C × R × N``
(``Po``, ``Pc``, acting on scene rows) and ``C × S × M`` (``Qo``, ``Qc``, acting on scene
columns), in DN above black per display unit per scene pixel. It is saved as one ``.npz``
(float32 by default, compressed) whose ``meta_json`` entry holds the metadata as JSON.

Constructors: :meth:`SystemMatrices.two_term_fit` (best two-term separable fit to a
simulator) and :meth:`SystemMatrices.direct` (the paper's direct generation from φ).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from thintact_sdk.errors import CalibrationError, InvalidShapeError

if TYPE_CHECKING:
    from thintact_sdk.formats.profiles import Profile

SYSTEM_MATRICES_FORMAT = "thintact-system-matrices/1"
_KEYS = ("Po", "Qo", "Pc", "Qc")


def _as_stack(a: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise CalibrationError(f"system matrix {name} must be C×rows×cols, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.floating):
        arr = arr.astype(np.float64)
    return arr


@dataclass
class SystemMatrices:
    """The T2S system matrices of a device, one set per channel.

    Parameters
    ----------
    Po, Pc
        ``C × R × N`` open / coding matrices acting on scene rows (a 2-D ``R × N`` array is
        taken as one channel), DN per display unit per scene pixel.
    Qo, Qc
        ``C × S × M`` open / coding matrices acting on scene columns.
    meta
        Free-form JSON-serialisable metadata (profile name, source, fit error, ...).
    """

    Po: np.ndarray
    Qo: np.ndarray
    Pc: np.ndarray
    Qc: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.Po = _as_stack(self.Po, "Po")
        self.Qo = _as_stack(self.Qo, "Qo")
        self.Pc = _as_stack(self.Pc, "Pc")
        self.Qc = _as_stack(self.Qc, "Qc")
        if self.Po.shape != self.Pc.shape:
            raise CalibrationError(f"Po {self.Po.shape} and Pc {self.Pc.shape} differ in shape")
        if self.Qo.shape != self.Qc.shape:
            raise CalibrationError(f"Qo {self.Qo.shape} and Qc {self.Qc.shape} differ in shape")
        if self.Po.shape[0] != self.Qo.shape[0]:
            raise CalibrationError(
                f"P has {self.Po.shape[0]} channels but Q has {self.Qo.shape[0]}"
            )
        self.meta = dict(self.meta)

    # -- shape -------------------------------------------------------------------------
    @property
    def channels(self) -> int:
        """Number of channels C."""
        return int(self.Po.shape[0])

    @property
    def sensor_shape(self) -> tuple[int, int]:
        """``(R, S)``: measurement rows and columns."""
        return int(self.Po.shape[1]), int(self.Qo.shape[1])

    @property
    def scene_shape(self) -> tuple[int, int]:
        """``(N, M)``: scene rows and columns."""
        return int(self.Po.shape[2]), int(self.Qo.shape[2])

    def channel(self, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(Po, Qo, Pc, Qc)`` of channel ``c`` (2-D views)."""
        return self.Po[c], self.Qo[c], self.Pc[c], self.Qc[c]

    def astype(self, dtype: Any) -> SystemMatrices:
        """A copy with every matrix converted to ``dtype``."""
        return SystemMatrices(
            self.Po.astype(dtype), self.Qo.astype(dtype), self.Pc.astype(dtype),
            self.Qc.astype(dtype), dict(self.meta),
        )

    # -- forward model -----------------------------------------------------------------
    def _check_scene(self, scene: np.ndarray) -> np.ndarray:
        x = np.asarray(scene)
        if x.ndim == 2:
            x = x[..., None]
        if x.ndim != 3 or x.shape[:2] != self.scene_shape:
            raise InvalidShapeError(f"scene must be {self.scene_shape[0]}×{self.scene_shape[1]}×C, got {x.shape}")
        if x.shape[2] != self.channels and self.channels != 1:
            raise InvalidShapeError(f"scene has {x.shape[2]} channels, system matrices {self.channels}")
        return x

    def _apply(self, P: np.ndarray, Q: np.ndarray, scene: np.ndarray) -> np.ndarray:  # noqa: N803
        x = self._check_scene(scene)
        out = np.empty((*self.sensor_shape, x.shape[2]), np.result_type(P.dtype, x.dtype, np.float32))
        for c in range(x.shape[2]):
            k = c if P.shape[0] > 1 else 0
            out[..., c] = P[k] @ x[..., c] @ Q[k].T
        return out

    def forward_open(self, scene: np.ndarray) -> np.ndarray:
        """Open component ``Po X Qoᵀ`` per channel: ``N × M × C`` → ``R × S × C`` (DN)."""
        return self._apply(self.Po, self.Qo, scene)

    def forward_coding(self, scene: np.ndarray) -> np.ndarray:
        """Coding component ``Pc X Qcᵀ`` per channel: ``N × M × C`` → ``R × S × C`` (DN)."""
        return self._apply(self.Pc, self.Qc, scene)

    def forward(self, scene: np.ndarray) -> np.ndarray:
        """Noiseless signal ``Po X Qoᵀ + Pc X Qcᵀ``: ``N × M × C`` → ``R × S × C`` (DN above black)."""
        return self.forward_open(scene) + self.forward_coding(scene)

    def relative_error(self, other: SystemMatrices) -> float:
        """Relative Frobenius error of the full operators, ``‖A − B‖ / ‖B‖`` with ``B = other``.

        Computed from the small Gram matrices of the Kronecker terms (never forms the
        ``RS × NM`` operator).
        """
        num = 0.0
        den = 0.0
        for c in range(max(self.channels, other.channels)):
            a = self.channel(min(c, self.channels - 1))
            b = other.channel(min(c, other.channels - 1))
            reference = [(1.0, b[0], b[1]), (1.0, b[2], b[3])]
            num += kron_sum_norm2([(1.0, a[0], a[1]), (1.0, a[2], a[3])] + [(-1.0, p, q) for _, p, q in reference])
            den += kron_sum_norm2(reference)
        return float(np.sqrt(max(num, 0.0) / den)) if den > 0 else float("inf")

    # -- persistence -------------------------------------------------------------------
    def save(self, path: str | os.PathLike[str], dtype: Any = np.float32) -> Path:
        """Write a compressed ``.npz`` (matrices in ``dtype``, metadata as JSON); returns the path."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        meta = {"format": SYSTEM_MATRICES_FORMAT, **self.meta}
        arrays = {k: np.asarray(getattr(self, k), dtype) for k in _KEYS}
        with open(p, "wb") as f:
            np.savez_compressed(f, meta_json=np.array(json.dumps(meta)), **arrays)  # type: ignore[arg-type]
        return p

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> SystemMatrices:
        """Read a file written by :meth:`save`; raises CalibrationError when unusable."""
        from thintact_sdk.formats.bundle_npz import read_npz

        p = Path(path)
        arrays, meta = read_npz(p, "system matrices", _KEYS)
        fmt = meta.pop("format", SYSTEM_MATRICES_FORMAT)
        if fmt != SYSTEM_MATRICES_FORMAT:
            raise CalibrationError(f"{p}: unknown format {fmt!r}; expected {SYSTEM_MATRICES_FORMAT!r}")
        try:
            return cls(meta=meta, **arrays)
        except CalibrationError as err:
            raise CalibrationError(f"{p}: {err}") from None

    # -- constructors ------------------------------------------------------------------
    @classmethod
    def two_term_fit(
        cls, simulator: Any, scale_dn: float = 1.0, channels: list[int] | None = None
    ) -> SystemMatrices:
        """Best two-term separable fit to a simulator's separable expansion.

        The open part ``Σ_k Q_k ⊗ P_k`` and the coding part are each replaced by their best
        rank-1 Kronecker approximation (Van Loan–Pitsianis, computed through the small Gram
        matrices of the terms; the big operator is never formed).

        Parameters
        ----------
        simulator
            Object with ``open_coding_terms(channel) -> (open_terms, coding_terms)``, lists of
            ``(P: R×N, Q: S×M)`` (the SIM contract) and a ``profile``.
        scale_dn
            DN per simulator unit (``thintact_sdk.device.virtual_bench.signal_scale_dn``).
        channels
            Channels to fit; default all of the simulator's profile.

        Returns
        -------
        SystemMatrices
            ``meta["fit_relative_error"]`` holds the relative Frobenius error of the fitted
            operator against the simulator's, per channel.
        """
        from thintact_sdk.reconstruction.kron import nearest_kron

        profile = getattr(simulator, "profile", None)
        if channels is None:
            n_ch = len(profile.sensor.channels) if profile is not None else 3
            channels = list(range(n_ch))
        mats: dict[str, list[np.ndarray]] = {k: [] for k in _KEYS}
        errors: list[float] = []
        for c in channels:
            open_terms, coding_terms = simulator.open_coding_terms(c)
            po, qo = nearest_kron(open_terms)
            pc, qc = nearest_kron(coding_terms)
            s = np.sqrt(float(scale_dn))
            for k, v in zip(_KEYS, (po * s, qo * s, pc * s, qc * s), strict=True):
                mats[k].append(v)
            full = [(1.0, p, q) for p, q in open_terms] + [(1.0, p, q) for p, q in coding_terms]
            fitted = [(-1.0, po, qo), (-1.0, pc, qc)]
            num = kron_sum_norm2(full + fitted)
            den = kron_sum_norm2(full)
            errors.append(float(np.sqrt(max(num, 0.0) / den)) if den > 0 else float("inf"))
        meta: dict[str, Any] = {
            "source": "simulator",
            "scale_dn": float(scale_dn),
            "fit_relative_error": errors,
        }
        if profile is not None:
            meta.update(profile=profile.name, profile_hash=profile.content_hash())
        po, qo, pc, qc = (np.stack(mats[k]) for k in _KEYS)
        return cls(po, qo, pc, qc, meta)

    @classmethod
    def direct(
        cls, profile: Profile, d_stripe_px: float | None = None, scale_dn: float = 1.0
    ) -> SystemMatrices:
        """The paper's direct generation of the system matrices from φ (§C), same for every channel.

        Uses :func:`thintact_sdk.reconstruction.direct_generation.direct_system_matrices` with the
        mask's ``phi`` (columns) and ``phi_rows`` (rows) and the pose in the profile's
        ``physics``; the matrices are multiplied by ``sqrt(scale_dn)`` each so the model is in
        DN. ``meta["unmodelled_angle_deg"]`` is the mask rotation a separable model leaves out.
        """
        from thintact_sdk.reconstruction.direct_generation import MaskPose, direct_system_matrices

        phi = np.asarray(profile.mask.phi, np.int8)
        phi_rows = np.asarray(profile.mask.rows_vector, np.int8)
        po, qo, pc, qc = direct_system_matrices(phi, profile, d_stripe_px, phi_rows=phi_rows)
        n_ch = len(profile.sensor.channels)
        s = np.sqrt(float(scale_dn))
        stacks = [np.repeat(np.asarray(m, np.float64)[None] * s, n_ch, axis=0) for m in (po, qo, pc, qc)]
        return cls(
            stacks[0], stacks[1], stacks[2], stacks[3],
            {
                "source": "direct",
                "profile": profile.name,
                "profile_hash": profile.content_hash(),
                "d_stripe_px": d_stripe_px,
                "scale_dn": float(scale_dn),
                "unmodelled_angle_deg": MaskPose.of(profile).angle_deg,
            },
        )


def kron_sum_norm2(terms: list[tuple[float, np.ndarray, np.ndarray]]) -> float:
    """``‖Σ_k w_k Q_k ⊗ P_k‖_F²`` from the Gram matrices: ``Σ_jk w_j w_k ⟨P_j,P_k⟩⟨Q_j,Q_k⟩``.

    Parameters
    ----------
    terms
        ``(w, P: R×N, Q: S×M)`` triples.
    """
    if not terms:
        return 0.0
    w = np.array([t[0] for t in terms], np.float64)
    ps = np.stack([np.asarray(t[1], np.float64).ravel() for t in terms])
    qs = np.stack([np.asarray(t[2], np.float64).ravel() for t in terms])
    gram = (ps @ ps.T) * (qs @ qs.T)
    return float(w @ gram @ w)
