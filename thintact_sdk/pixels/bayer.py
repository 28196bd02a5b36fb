"""Raw Bayer mosaic → measurement channels.

The paper's layout (§IV) bins each 2×2 cell to R, mean of the two G, B (:func:`bin_bayer`).
A profile with ``sensor.channels: [R, Gr, Gb, B]`` keeps the four sites as separate planes
instead (FlatCam's layout, :func:`split_bayer`): Gr is the green on the red row, Gb the green
on the blue row; each plane is calibrated and decoded on its own and :func:`planes_to_rgb`
combines Gr and Gb after decoding where RGB is needed (the tactile pipeline).
Every camera frame goes through :func:`thintact_sdk.device.cameras.to_measurement`, which picks
one of these, so binning is done one way only.

This module is where all binning lives: the ``2 × 2`` Bayer cell, the ``2b × 2b`` cell per colour
site of a decoder declaring ``input = "binned"`` with ``sensor_bin = b`` (:func:`bin_sites`, in
one pass; :meth:`thintact_sdk.device.sensor.Sensor.decoder_input` asks for it), and the
``b × b`` block means of a measurement (:func:`block_mean`, which such a decoder uses on a full
frame handed to it outside a Sensor).
"""

from __future__ import annotations

import threading

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
    one contiguous plane: binning writes it with unit stride and the decoders take the planes
    as their channel-first GEMM operand without a copy (:meth:`ArrayBackend.channels_first
    <thintact_sdk.reconstruction.decoders.backend.ArrayBackend.channels_first>`), so no
    conversion pass runs per frame. It indexes like any ``R × S × C`` array; ``np.ascontiguousarray``
    gives the interleaved layout where one is needed.
    """
    return np.moveaxis(np.empty((channels, rows, cols), np.float32), 0, -1)


def bin_bayer(raw: np.ndarray, pattern: str = "RGGB", out: np.ndarray | None = None,
              block: int = 1) -> np.ndarray:
    """Bin a Bayer mosaic into a half-resolution R, G, B image.

    Parameters
    ----------
    raw
        ``H × W`` integer or float mosaic in DN; H and W even (multiples of ``2·block``).
    pattern
        CFA layout: ``RGGB``, ``BGGR``, ``GRBG`` or ``GBRG``. ``none`` passes an
        ``H × W × 3`` RGB frame through unchanged (as float32; with ``block`` > 1, its
        ``block × block`` means, :func:`block_mean`).
    out
        Optional preallocated ``H/(2·block) × W/(2·block) × 3`` float32 array.
    block
        ``b``: also average ``b × b`` binned pixels, in the same pass (each output pixel is the
        mean of the ``b²`` R sites, the ``2b²`` G sites and the ``b²`` B sites of a
        ``2b × 2b`` block of the mosaic): what binning then :func:`block_mean` give, up to
        float32 rounding (exactly for integer DN and ``b`` a power of 2), in one read of the
        mosaic (:func:`bin_sites`).

    Returns
    -------
    numpy.ndarray
        ``H/(2b) × W/(2b) × 3`` float32 in DN (black level untouched): R, (G1 + G2)/2, B;
        without ``out``, a view of channel-planar storage (:func:`planar_frame`).
    """
    if pattern == "none":
        if raw.ndim != 3 or raw.shape[2] != 3:
            raise InvalidShapeError(f"pattern 'none' needs an H×W×3 frame, got shape {raw.shape}")
        return raw.astype(np.float32, copy=False) if block == 1 else block_mean(raw, block, out)
    if pattern not in _CFA_OFFSETS:
        raise InvalidValueError(f"unknown Bayer pattern {pattern!r}; one of {', '.join(_CFA_OFFSETS)} or 'none'")
    if raw.ndim != 2:
        raise InvalidShapeError(f"a Bayer mosaic is 2-D, got shape {raw.shape}")
    h, w = raw.shape
    if h % 2 or w % 2:
        raise InvalidShapeError(f"a Bayer mosaic needs even height and width, got {h}×{w}")
    (rr, rc), (g1r, g1c), (g2r, g2c), (br, bc) = _CFA_OFFSETS[pattern]
    if block != 1:
        return bin_sites(raw, (((rr, rc),), ((g1r, g1c), (g2r, g2c)), ((br, bc),)), block, out)
    if out is None:
        out = planar_frame(h // 2, w // 2, 3)
    out[..., 0] = raw[rr::2, rc::2]
    np.add(raw[g1r::2, g1c::2], raw[g2r::2, g2c::2], out=out[..., 1], dtype=np.float32)
    out[..., 1] *= np.float32(0.5)
    out[..., 2] = raw[br::2, bc::2]
    return out


_scratch = threading.local()


def _row_scratch(rows: int, cols: int) -> np.ndarray:
    """This thread's reusable ``rows × cols`` float32 work array (a fresh one per frame would
    cost its page faults on every frame)."""
    buf = getattr(_scratch, "rows", None)
    if buf is None or buf.shape != (rows, cols):
        buf = _scratch.rows = np.empty((rows, cols), np.float32)
    return buf


def bin_sites(raw: np.ndarray, channels: tuple[tuple[tuple[int, int], ...], ...], block: int,
              out: np.ndarray | None = None) -> np.ndarray:
    """Means over ``block × block`` cells of the given Bayer sites, straight from the mosaic.

    Output channel ``k``, pixel ``(i, j)``, is the mean of the mosaic at
    ``(2·(b·i + u) + r0, 2·(b·j + v) + c0)`` for ``u, v < b`` and every site ``(r0, c0)`` of
    ``channels[k]``. Two passes, both over contiguous memory where it counts: for each row
    parity, the ``b`` mosaic rows of a block are summed into one float32 row (reading the
    mosaic once, row by row), then each site's ``b`` columns of that row sum are added into
    its plane: one read of the mosaic, where binning then :func:`block_mean` reads the
    frame twice.

    Parameters
    ----------
    raw
        ``H × W`` mosaic in DN (any real dtype), ``H`` and ``W`` multiples of ``2·block``.
    channels
        Per output channel, its ``(row, col)`` offsets in the 2 × 2 CFA cell.
    block
        ``b`` ≥ 1.
    out
        Optional ``H/(2b) × W/(2b) × len(channels)`` float32 array.

    Returns
    -------
    numpy.ndarray
        float32 DN, channel-planar storage without ``out`` (:func:`planar_frame`).

    Raises
    ------
    InvalidShapeError
        When a side of the mosaic is not a multiple of ``2·block``.
    InvalidValueError
        When ``block`` < 1.
    """
    if block < 1:
        raise InvalidValueError(f"block must be a positive number of pixels, got {block}")
    h, w = raw.shape
    cell = 2 * block
    if h % cell or w % cell:
        raise InvalidShapeError(f"a {h}×{w} mosaic cannot be binned in {cell}×{cell} cells: "
                                f"both sides must be multiples of {cell}")
    rows, cols = h // cell, w // cell
    if out is None:
        out = planar_frame(rows, cols, len(channels))
    by_row = raw.reshape(rows, cell, w)  # by_row[i, k] is mosaic row cell·i + k
    acc = _row_scratch(rows, w)
    started = [False] * len(channels)
    for parity in (0, 1):
        sites = [(k, c0) for k, offs in enumerate(channels) for r0, c0 in offs if r0 == parity]
        if not sites:
            continue
        if block == 1:
            acc[...] = by_row[:, parity]
        else:
            np.add(by_row[:, parity], by_row[:, parity + 2], out=acc, dtype=np.float32)
            for u in range(2, block):
                np.add(acc, by_row[:, parity + 2 * u], out=acc, dtype=np.float32)
        by_col = acc.reshape(rows, cols, cell)  # by_col[i, j, k] is column cell·j + k
        for k, c0 in sites:
            plane = out[..., k]
            for v in range(block):
                if started[k]:
                    plane += by_col[..., c0 + 2 * v]
                else:
                    plane[...] = by_col[..., c0 + 2 * v]
                    started[k] = True
    for k, offs in enumerate(channels):
        out[..., k] *= np.float32(1.0 / (len(offs) * block * block))
    return out


def block_mean(frame: np.ndarray, b: int, out: np.ndarray | None = None, offset: float = 0.0) -> np.ndarray:
    """Block means of ``b × b`` pixels of each channel, minus ``offset``.

    Parameters
    ----------
    frame
        ``R × S × C`` DN (any real dtype, any layout), ``R`` and ``S`` multiples of ``b``.
    b
        Block side, pixels.
    out
        Optional ``R/b × S/b × C`` float32 result (reused across frames: no allocation).
    offset
        Subtracted from every block mean (the black level, DN).

    Returns
    -------
    numpy.ndarray
        ``R/b × S/b × C`` float32 in channel-planar storage (:func:`planar_frame`).

    Raises
    ------
    InvalidShapeError
        When ``R`` or ``S`` is not a multiple of ``b``.
    """
    r, s, c = frame.shape
    if r % b or s % b:
        raise InvalidShapeError(f"a {r}×{s} frame cannot be binned {b}×{b}: both sides must be multiples of {b}")
    if out is None:
        out = planar_frame(r // b, s // b, c)
    scale = np.float32(1.0 / (b * b))
    for ch in range(c):
        plane = out[..., ch]
        if b == 1:
            plane[...] = frame[..., ch]
        else:
            np.add(frame[0::b, 0::b, ch], frame[1::b, 0::b, ch], out=plane, dtype=np.float32)
            for i in range(b):
                for j in range(b):
                    if (i, j) not in ((0, 0), (1, 0)):
                        np.add(plane, frame[i::b, j::b, ch], out=plane, dtype=np.float32)
            plane *= scale
        if offset:
            plane -= np.float32(offset)
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


def split_bayer(raw: np.ndarray, pattern: str = "RGGB", out: np.ndarray | None = None,
                block: int = 1) -> np.ndarray:
    """Split a Bayer mosaic into its four site planes, ``H/2 × W/2 × 4``: R, Gr, Gb, B.

    Parameters
    ----------
    raw
        ``H × W`` mosaic in DN; H and W even (multiples of ``2·block``).
    pattern
        CFA layout: ``RGGB``, ``BGGR``, ``GRBG`` or ``GBRG``.
    out
        Optional preallocated ``H/(2·block) × W/(2·block) × 4`` float32 array.
    block
        ``b``: each plane's ``b × b`` means, in the same pass (:func:`bin_sites`).

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
    if block != 1:
        return bin_sites(raw, tuple((o,) for o in offsets), block, out)
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
