"""Raw Bayer mosaic → 3-channel measurement (paper §IV: R, mean of the two G, B).

Every camera plugin goes through :func:`bin_bayer`, so binning is done one way only.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.errors import InvalidShapeError, InvalidValueError

# offsets (row, col) of R, G1, G2, B inside the 2×2 cell for each CFA layout
_CFA_OFFSETS: dict[str, tuple[tuple[int, int], tuple[int, int], tuple[int, int], tuple[int, int]]] = {
    "RGGB": ((0, 0), (0, 1), (1, 0), (1, 1)),
    "BGGR": ((1, 1), (0, 1), (1, 0), (0, 0)),
    "GRBG": ((0, 1), (0, 0), (1, 1), (1, 0)),
    "GBRG": ((1, 0), (0, 0), (1, 1), (0, 1)),
}

_FORMAT_TO_PATTERN = {"BayerRG": "RGGB", "BayerBG": "BGGR", "BayerGR": "GRBG", "BayerGB": "GBRG"}


def pattern_from_pixel_format(pixel_format: str) -> str | None:
    """CFA layout named by a GenICam pixel format (``BayerRG12`` → ``RGGB``); None if not Bayer."""
    for prefix, pat in _FORMAT_TO_PATTERN.items():
        if pixel_format.startswith(prefix):
            return pat
    return None


def bin_bayer(raw: np.ndarray, pattern: str = "RGGB", out: np.ndarray | None = None) -> np.ndarray:
    """Bin a Bayer mosaic into a half-resolution R, G, B image.

    Parameters
    ----------
    raw
        ``H × W`` integer or float mosaic in DN; H and W even.
    pattern
        CFA layout: ``RGGB``, ``BGGR``, ``GRBG`` or ``GBRG``. ``none`` passes an
        ``H × W × 3`` RGB frame through unchanged (as float32).
    out
        Optional preallocated ``H/2 × W/2 × 3`` float32 array.

    Returns
    -------
    numpy.ndarray
        ``H/2 × W/2 × 3`` float32 in DN (black level untouched): R, (G1 + G2)/2, B.
    """
    if pattern == "none":
        if raw.ndim != 3 or raw.shape[2] != 3:
            raise InvalidShapeError(f"pattern 'none' needs an H×W×3 frame, got shape {raw.shape}")
        return raw.astype(np.float32, copy=False)
    if pattern not in _CFA_OFFSETS:
        raise InvalidValueError(f"unknown Bayer pattern {pattern!r}; one of {', '.join(_CFA_OFFSETS)} or 'none'")
    if raw.ndim != 2:
        raise InvalidShapeError(f"a Bayer mosaic is 2-D, got shape {raw.shape}")
    h, w = raw.shape
    if h % 2 or w % 2:
        raise InvalidShapeError(f"a Bayer mosaic needs even height and width, got {h}×{w}")
    (rr, rc), (g1r, g1c), (g2r, g2c), (br, bc) = _CFA_OFFSETS[pattern]
    if out is None:
        out = np.empty((h // 2, w // 2, 3), dtype=np.float32)
    out[..., 0] = raw[rr::2, rc::2]
    np.add(raw[g1r::2, g1c::2], raw[g2r::2, g2c::2], out=out[..., 1], dtype=np.float32)
    out[..., 1] *= np.float32(0.5)
    out[..., 2] = raw[br::2, bc::2]
    return out


def mosaic_from_rgb(rgb: np.ndarray, pattern: str = "RGGB") -> np.ndarray:
    """Inverse of :func:`bin_bayer` for simulation: ``R × S × 3`` → ``2R × 2S`` mosaic.

    Both green sites get the G value, so ``bin_bayer(mosaic_from_rgb(x)) == x``.
    The dtype of ``rgb`` is kept.
    """
    if pattern not in _CFA_OFFSETS:
        raise InvalidValueError(f"unknown Bayer pattern {pattern!r}")
    r, s, _ = rgb.shape
    mos = np.empty((2 * r, 2 * s), dtype=rgb.dtype)
    (rr, rc), (g1r, g1c), (g2r, g2c), (br, bc) = _CFA_OFFSETS[pattern]
    mos[rr::2, rc::2] = rgb[..., 0]
    mos[g1r::2, g1c::2] = rgb[..., 1]
    mos[g2r::2, g2c::2] = rgb[..., 1]
    mos[br::2, bc::2] = rgb[..., 2]
    return mos
