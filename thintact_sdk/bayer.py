"""Raw Bayer mosaic → measurement channels.

The paper's layout (§IV) bins each 2×2 cell to R, mean of the two G, B (:func:`bin_bayer`).
A profile with ``sensor.channels: [R, Gr, Gb, B]`` keeps the four sites as separate planes
instead (FlatCam's layout, :func:`split_bayer`): Gr is the green on the red row, Gb the green
on the blue row; each plane is calibrated and decoded on its own and :func:`planes_to_rgb`
combines Gr and Gb after decoding where RGB is needed (the tactile pipeline).
Every camera frame goes through :func:`thintact_sdk.capture.to_measurement`, which picks
one of these, so binning is done one way only.
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


def planar_frame(rows: int, cols: int, channels: int) -> np.ndarray:
    """An uninitialised ``rows × cols × channels`` float32 frame stored channel by channel.

    The array is a view of ``channels × rows × cols`` contiguous storage, so each channel is
    one contiguous plane: binning writes it with unit stride (paper device: 2.9 instead of
    3.8 ms per frame, Xeon-AMX, one thread) and the decoders take the planes as their
    channel-first GEMM operand without a copy (:meth:`ArrayBackend.channels_first
    <thintact_decoders.backend.ArrayBackend.channels_first>`), which saved a 3.5 ms pass per
    paper-size frame. It indexes like any ``R × S × C`` array; ``np.ascontiguousarray``
    gives the interleaved layout where one is needed.
    """
    return np.moveaxis(np.empty((channels, rows, cols), np.float32), 0, -1)


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
        ``H/2 × W/2 × 3`` float32 in DN (black level untouched): R, (G1 + G2)/2, B; without
        ``out``, a view of channel-planar storage (:func:`planar_frame`).
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
        out = planar_frame(h // 2, w // 2, 3)
    out[..., 0] = raw[rr::2, rc::2]
    np.add(raw[g1r::2, g1c::2], raw[g2r::2, g2c::2], out=out[..., 1], dtype=np.float32)
    out[..., 1] *= np.float32(0.5)
    out[..., 2] = raw[br::2, bc::2]
    return out


PLANES = ("R", "Gr", "Gb", "B")
"""The per-Bayer-site channel layout (FlatCam's), in this order."""


def _site_offsets(pattern: str) -> tuple[tuple[int, int], ...]:
    """(row, col) offsets of R, Gr, Gb, B for a CFA layout (Gr shares R's row)."""
    if pattern not in _CFA_OFFSETS:
        raise InvalidValueError(f"unknown Bayer pattern {pattern!r}; one of {', '.join(_CFA_OFFSETS)}")
    r, g1, g2, b = _CFA_OFFSETS[pattern]
    gr, gb = (g1, g2) if g1[0] == r[0] else (g2, g1)
    return r, gr, gb, b


def split_bayer(raw: np.ndarray, pattern: str = "RGGB", out: np.ndarray | None = None) -> np.ndarray:
    """Split a Bayer mosaic into its four site planes, ``H/2 × W/2 × 4``: R, Gr, Gb, B.

    Parameters
    ----------
    raw
        ``H × W`` mosaic in DN; H and W even.
    pattern
        CFA layout: ``RGGB``, ``BGGR``, ``GRBG`` or ``GBRG``.
    out
        Optional preallocated ``H/2 × W/2 × 4`` float32 array.

    Returns
    -------
    numpy.ndarray
        float32 DN (black level untouched), planes in :data:`PLANES` order; without ``out``,
        a view of channel-planar storage (:func:`planar_frame`).
    """
    offsets = _site_offsets(pattern)
    if raw.ndim != 2:
        raise InvalidShapeError(f"a Bayer mosaic is 2-D, got shape {raw.shape}")
    h, w = raw.shape
    if h % 2 or w % 2:
        raise InvalidShapeError(f"a Bayer mosaic needs even height and width, got {h}×{w}")
    if out is None:
        out = planar_frame(h // 2, w // 2, 4)
    for k, (r0, c0) in enumerate(offsets):
        out[..., k] = raw[r0::2, c0::2]
    return out


def mosaic_from_planes(planes: np.ndarray, pattern: str = "RGGB") -> np.ndarray:
    """Inverse of :func:`split_bayer` for simulation: ``R × S × 4`` → ``2R × 2S`` (dtype kept)."""
    offsets = _site_offsets(pattern)
    if planes.ndim != 3 or planes.shape[2] != 4:
        raise InvalidShapeError(f"per-site planes are R×S×4, got shape {planes.shape}")
    r, s, _ = planes.shape
    mos = np.empty((2 * r, 2 * s), dtype=planes.dtype)
    for k, (r0, c0) in enumerate(offsets):
        mos[r0::2, c0::2] = planes[..., k]
    return mos


def planes_to_rgb(x: np.ndarray) -> np.ndarray:
    """``… × 4`` (R, Gr, Gb, B) → ``… × 3`` (R, (Gr + Gb)/2, B), e.g. a decoded scene for RGB
    consumers; other channel counts are returned unchanged."""
    if x.shape[-1] != 4:
        return x
    return np.stack([x[..., 0], 0.5 * (x[..., 1] + x[..., 2]), x[..., 3]], axis=-1).astype(x.dtype, copy=False)


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
