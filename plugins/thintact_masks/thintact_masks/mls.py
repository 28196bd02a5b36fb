"""Maximal-length sequences (MLS) from primitive LFSR polynomials, and the MLS mask designer.

The paper's baseline mask (after FlatCam) is a 255-length MLS repeated 3× to 765 cells.
:func:`mls_sequence` gives a ±1 MLS of length ``2**bits − 1`` from a Fibonacci LFSR whose
feedback polynomial is primitive over GF(2); :class:`MLSDesigner` repeats (and truncates)
it to any mask length K.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.errors import InvalidValueError
from thintact_sdk.interfaces import Mask, MaskDesigner

#: Exponents of primitive polynomials x^n + ... + 1 over GF(2) (feedback taps), n = 2..16.
PRIMITIVE_TAPS: dict[int, tuple[int, ...]] = {
    2: (2, 1), 3: (3, 2), 4: (4, 3), 5: (5, 3), 6: (6, 5), 7: (7, 6), 8: (8, 6, 5, 4),
    9: (9, 5), 10: (10, 7), 11: (11, 9), 12: (12, 11, 10, 4), 13: (13, 12, 11, 8),
    14: (14, 13, 12, 2), 15: (15, 14), 16: (16, 15, 13, 4),
}


def mls_bits(bits: int = 8) -> np.ndarray:
    """One period of the binary MLS of order ``bits`` (length ``2**bits − 1``, values 0/1).

    The Fibonacci LFSR starts from the all-ones state and feeds back the XOR of the taps of
    :data:`PRIMITIVE_TAPS`; the output is the register's last stage.
    """
    if bits not in PRIMITIVE_TAPS:
        raise InvalidValueError(f"MLS order must be in {min(PRIMITIVE_TAPS)}..{max(PRIMITIVE_TAPS)}, got {bits}")
    taps = PRIMITIVE_TAPS[bits]
    state = [1] * bits
    out = np.empty(2**bits - 1, np.int8)
    for i in range(out.size):
        out[i] = state[-1]
        feedback = 0
        for t in taps:
            feedback ^= state[t - 1]
        state = [feedback] + state[:-1]
    return out


def mls_sequence(bits: int = 8) -> np.ndarray:
    """±1 MLS of length ``2**bits − 1`` (bit 1 → +1, bit 0 → −1), int8."""
    return (2 * mls_bits(bits) - 1).astype(np.int8)


def repeat_to_length(seq: np.ndarray, K: int) -> np.ndarray:  # noqa: N803
    """``seq`` repeated and truncated to exactly ``K`` entries (255 → 765 is the paper's 3×)."""
    if K <= 0:
        raise InvalidValueError(f"K must be positive, got {K}")
    reps = -(-K // seq.size)
    return np.tile(seq, reps)[:K].copy()


class MLSDesigner(MaskDesigner):
    """The paper's baseline: an MLS of order ``bits`` (default 8 → 255) repeated to K cells."""

    name = "mls"

    def design(self, K: int, feature_um: float, **options: Any) -> Mask:  # noqa: N803
        """MLS mask of ``K`` cells of side ``feature_um`` (um); option ``bits`` (default 8)."""
        bits = int(options.get("bits", 8))
        phi = repeat_to_length(mls_sequence(bits), K)
        return Mask(phi=phi, feature_um=float(feature_um), design="mls",
                    provenance={"bits": bits, "period": 2**bits - 1,
                                "polynomial_taps": list(PRIMITIVE_TAPS[bits]),
                                "repeats": K / (2**bits - 1)})


class RandomDesigner(MaskDesigner):
    """Uniform random ±1 mask vector from a seeded numpy generator."""

    name = "random"

    def design(self, K: int, feature_um: float, **options: Any) -> Mask:  # noqa: N803
        """Random mask of ``K`` cells of side ``feature_um`` (um); option ``seed`` (default 0)."""
        if K <= 0:
            raise InvalidValueError(f"K must be positive, got {K}")
        seed = int(options.get("seed", 0))
        phi = random_phi(K, seed)
        return Mask(phi=phi, feature_um=float(feature_um), design="random",
                    provenance={"seed": seed, "generator": "numpy PCG64"})


def random_phi(K: int, seed: int) -> np.ndarray:  # noqa: N803
    """``K`` independent fair ±1 entries (int8) from ``numpy.random.default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    return (2 * rng.integers(0, 2, size=K) - 1).astype(np.int8)
