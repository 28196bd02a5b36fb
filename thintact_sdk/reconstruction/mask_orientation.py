"""The eight ways a square separable mask can be mounted: quarter turns and mirror flips.

A K×K mask ``T(p) = (1 + φ_rows[i(p_y)]·φ[j(p_x)])/2`` (CONTRACTS §1) read at ``G·q``, with
``G`` one of the 8 signed permutation matrices of the square's symmetry group, is again such a
mask: a mirror along x reverses φ, along y reverses φ_rows, and swapping the axes swaps the
two vectors. So every such pose is *exact* in the contract's own terms, by rewriting the
mask vectors, and stays separable; what is left for ``mask_misalignment`` is a small residual
turn and the offset. The cell boundaries map onto cell boundaries because the mask is
centred on the axis (cell ``j`` of ``x`` is cell ``K − 1 − j`` of ``−x``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Orientation:
    """One of the 8 mountings of the mask relative to its design.

    The mounted pattern is the design read at ``p = G·q`` (``q`` in the mounted frame), where
    ``G = S·diag(±1, ±1)`` (``S`` the axis swap when ``transpose``): the mounted mask vectors
    are :meth:`apply` of the design's.

    Attributes
    ----------
    transpose
        x and y are swapped (φ runs along the rows, φ_rows along the columns).
    mirror_x
        The mounted φ (along x, columns) is reversed.
    mirror_y
        The mounted φ_rows (along y, rows) is reversed.
    """

    transpose: bool = False
    mirror_x: bool = False
    mirror_y: bool = False

    def apply(self, phi: np.ndarray, phi_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mounted ``(φ, φ_rows)`` (along x, along y) from the design's, each ``(K,)``."""
        x, y = (np.asarray(phi_rows), np.asarray(phi)) if self.transpose else (np.asarray(phi),
                                                                               np.asarray(phi_rows))
        return (x[::-1] if self.mirror_x else x), (y[::-1] if self.mirror_y else y)

    @property
    def matrix(self) -> np.ndarray:
        """``G`` (2×2 integer): the design coordinates ``p = G·q`` of a mounted point ``q``."""
        g = np.array([[0, 1], [1, 0]]) if self.transpose else np.eye(2, dtype=int)
        return g @ np.diag([-1 if self.mirror_x else 1, -1 if self.mirror_y else 1])

    @property
    def mirrored(self) -> bool:
        """True for the four mirror images (det G = −1), which no turn reproduces."""
        return bool(round(np.linalg.det(self.matrix)) < 0)

    @property
    def turn_deg(self) -> int:
        """The turn of the mounted mask, degrees, +x towards +y (0, 90, 180 or 270); for a
        mirror image, the turn that follows a left-right mirror (x → −x)."""
        # turned by a: G = Rot(−a) = [[c, s], [−s, c]]; mirrored first: G = diag(−1, 1)·Rot(−a)
        g = np.diag([-1, 1]) @ self.matrix if self.mirrored else self.matrix
        return int(round(np.degrees(np.arctan2(g[0, 1], g[0, 0])))) % 360

    @property
    def name(self) -> str:
        """In words: ``"as designed"``, ``"turned by 90°"``, ``"mirrored left-right"``, …"""
        if not self.mirrored:
            return "as designed" if self.turn_deg == 0 else f"turned by {self.turn_deg}°"
        words = {0: "mirrored left-right", 180: "mirrored top-bottom",
                 90: "mirrored about the anti-diagonal (x, y → −y, −x)",
                 270: "mirrored about the diagonal (x ↔ y)"}
        return words[self.turn_deg]

    def to_json(self) -> dict[str, object]:
        return {"name": self.name, "turn_deg": self.turn_deg, "mirrored": self.mirrored,
                "transpose": self.transpose, "mirror_x": self.mirror_x, "mirror_y": self.mirror_y}

    @classmethod
    def turned(cls, quarter_turns: int) -> Orientation:
        """The mask turned by ``90° × quarter_turns`` (+x towards +y)."""
        return {0: cls(), 1: cls(True, True, False), 2: cls(False, True, True),
                3: cls(True, False, True)}[quarter_turns % 4]


ORIENTATIONS: tuple[Orientation, ...] = tuple(Orientation.turned(k) for k in range(4)) + (
    Orientation(False, True, False), Orientation(False, False, True), Orientation(True, False, False),
    Orientation(True, True, True))
"""All 8 mountings: the design's own, the turns by 90°, 180° and 270°, then the four mirror
images (left-right, top-bottom, about the diagonal and the anti-diagonal)."""


def split_angle(angle_deg: float) -> tuple[Orientation, float]:
    """A turn of any size as the nearest quarter turn (exact, see :class:`Orientation`) and
    the residual in (−45°, 45°]."""
    k = int(np.floor((angle_deg + 45.0) / 90.0))
    residual = angle_deg - 90.0 * k
    if residual <= -45.0:
        k, residual = k - 1, residual + 90.0
    return Orientation.turned(k), float(residual)
