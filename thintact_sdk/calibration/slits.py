"""Slit measurements of one channel, compressed, ready for Algorithms 1-3.

Orientation convention: a :class:`SlitStack` holds ``n`` images oriented so that the T2S
model reads ``Y_i ≈ a_i u_iᵀ + b_i w_iᵀ``, with ``a_i, b_i`` the unknown columns (length
``R`` for horizontal slits) and ``u_i, w_i`` known from the other pair of matrices. Vertical
slits are stored transposed (``Y_vjᵀ``), exactly as the paper feeds them to Algorithm 1.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from thintact_sdk.calibration.lowrank import LowRankImage
from thintact_sdk.errors import InvalidValueError


@dataclass
class SlitStack:
    """``n`` compressed slit images of one channel and orientation.

    Attributes
    ----------
    index
        ``(n,)`` scene row (horizontal) or column (vertical) each slit lights.
    profile
        ``n × L`` float64: the slit's values along its length (``L = M`` for a horizontal
        slit, ``N`` for a vertical one); a paper slit is all ones.
    left
        ``n × A × k`` float64 factors (``A = R`` horizontal, ``S`` vertical after transposing).
    right
        ``n × B × k`` float64 factors (``B = S`` horizontal, ``R`` vertical).
    energy
        ``(n,)`` ‖Y_i‖²_F in DN².
    """

    index: np.ndarray
    profile: np.ndarray
    left: np.ndarray
    right: np.ndarray
    energy: np.ndarray

    @classmethod
    def from_images(
        cls, index: list[int], profile: list[np.ndarray], images: list[LowRankImage]
    ) -> SlitStack:
        """Stack compressed images (already oriented) with their indices and profiles."""
        if not images:
            raise InvalidValueError("a slit stack needs at least one image")
        k = max(im.left.shape[1] for im in images)

        def pad(a: np.ndarray) -> np.ndarray:
            return np.pad(a, ((0, 0), (0, k - a.shape[1])))

        order = np.argsort(np.asarray(index), kind="stable")
        return cls(
            index=np.asarray(index, dtype=np.int64)[order],
            profile=np.asarray(profile, dtype=np.float64)[order],
            left=np.stack([pad(images[i].left) for i in order]),
            right=np.stack([pad(images[i].right) for i in order]),
            energy=np.asarray([images[i].energy for i in order], dtype=np.float64),
        )

    @property
    def count(self) -> int:
        return int(self.index.shape[0])

    @property
    def out_len(self) -> int:
        """Length of the unknown columns ``a_i`` (``R`` or ``S``)."""
        return int(self.left.shape[1])

    @property
    def in_len(self) -> int:
        """Length of the known vectors ``u_i`` (``S`` or ``R``)."""
        return int(self.right.shape[1])

    def times(self, vectors: np.ndarray) -> np.ndarray:
        """``Y_i v_i`` for every slit: ``vectors`` is ``n × B`` → ``n × A``."""
        t = np.einsum("nbk,nb->nk", self.right, vectors)
        return np.einsum("nak,nk->na", self.left, t)

    def times_transposed(self, vectors: np.ndarray) -> np.ndarray:
        """``Y_iᵀ v_i`` for every slit: ``vectors`` is ``n × A`` → ``n × B``."""
        t = np.einsum("nak,na->nk", self.left, vectors)
        return np.einsum("nbk,nk->nb", self.right, t)

    def image(self, i: int) -> np.ndarray:
        """Slit ``i`` (position in the stack) as a dense ``A × B`` array (for tests, figures)."""
        return self.left[i] @ self.right[i].T

    def largest(self) -> int:
        """Position of the slit with the most energy (the paper's centre slit, made robust
        to a sensing area that is not centred on the sensor)."""
        return int(np.argmax(self.energy))


@dataclass
class ChannelSlits:
    """Horizontal and (transposed) vertical slits of one channel."""

    horizontal: SlitStack
    vertical: SlitStack
    n_rows: int
    n_cols: int
    meta: dict[str, object] = field(default_factory=dict)

    def check_complete(self) -> list[str]:
        """Problems that make the solve impossible (missing rows/columns), as sentences."""
        problems = []
        for name, stack, n in (("row", self.horizontal, self.n_rows), ("column", self.vertical, self.n_cols)):
            missing = sorted(set(range(n)) - set(int(i) for i in stack.index))
            if missing:
                head = ", ".join(str(i) for i in missing[:8]) + (" …" if len(missing) > 8 else "")
                problems.append(f"no slit for scene {name}(s) {head} ({len(missing)} of {n} missing)")
        return problems
