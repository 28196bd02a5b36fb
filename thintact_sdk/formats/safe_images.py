"""Reading untrusted image files (PNG, JPEG, TIFF, BMP) without decoding a bomb.

An image file's header declares its size, and a few kilobytes of compressed PNG can declare
gigabytes of pixels: decoding first and checking after lets such a file take the host's
memory. So the header is read first (Pillow reads only the header on ``open``), the bytes the
decoded image will take (width × height × channels × bytes per sample) are compared with
:func:`~thintact_sdk.formats.safe_arrays.array_size_limit` (the same bound as for
``.npy`` files), summed over every file one operation reads, and only then is anything
decoded (OpenCV). A file whose header cannot be read, or that declares more pixels than
Pillow's own bomb bound, is refused with one :class:`~thintact_sdk.errors.ThinTactError` of
the caller's choice naming the file.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.safe_arrays import array_size_limit, format_bytes

_SAMPLE_BYTES = {"I;16": 2, "I;16B": 2, "I;16L": 2, "I;16N": 2, "I": 4, "F": 4}
"""Bytes per sample of Pillow's wider modes (every other mode: one byte per band)."""
DECODED_CHANNELS_AT_LEAST = 3
"""A palette or grey file read as colour decodes to three channels."""


def declared_image_bytes(path: str | Path, error: type[ThinTactError] = ThinTactError) -> int:
    """Bytes the decoded image of ``path`` will take, from its header alone (nothing decoded).

    Raises
    ------
    error
        The header cannot be read (not an image, damaged) or declares more pixels than
        Pillow's decompression-bomb bound.
    """
    from PIL import Image, UnidentifiedImageError

    p = Path(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(p) as im:
                width, height = im.size
                bands = len(im.getbands())
                sample = _SAMPLE_BYTES.get(im.mode, 1)
    except Image.DecompressionBombError as err:
        raise error(f"{p}: refused, the image declares too many pixels ({err})") from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, EOFError) as err:
        raise error(f"{p}: not a readable image ({type(err).__name__}: {err})") from None
    if width < 1 or height < 1:
        raise error(f"{p}: the image declares {width}×{height} px")
    return int(width) * int(height) * max(bands, DECODED_CHANNELS_AT_LEAST) * sample


def check_image_budget(paths: Sequence[str | Path], error: type[ThinTactError] = ThinTactError,
                       limit_bytes: int | None = None) -> int:
    """Refuse, before anything is decoded, images whose decoded sizes sum to more than
    ``limit_bytes`` (default :func:`~thintact_sdk.formats.safe_arrays.array_size_limit`).
    Returns the declared total in bytes.

    Raises
    ------
    error
        A header cannot be read, or the total is over the limit (the message names the
        largest file, the total and the limit).
    """
    sizes = [(declared_image_bytes(p, error), Path(p)) for p in paths]
    total = sum(s for s, _ in sizes)
    limit = array_size_limit() if limit_bytes is None else int(limit_bytes)
    if total > limit:
        largest, where = max(sizes, key=lambda item: item[0])
        what = f"{where}" if len(sizes) == 1 else f"{len(sizes)} images (the largest {where}: {format_bytes(largest)})"
        raise error(f"{what} would take {format_bytes(total)} decoded, more than this host allows "
                    f"for one file set ({format_bytes(limit)}, half the available memory)")
    return total


def check_video_frames(cap: Any, path: str | Path, error: type[ThinTactError] = ThinTactError) -> None:
    """Refuse a video whose frames (width × height × 3 bytes, as ``cv2.VideoCapture`` delivers
    them) would be over :func:`~thintact_sdk.formats.safe_arrays.array_size_limit`, from the
    size the opened ``cap`` reports, before a frame is decoded (an MJPEG frame may declare
    65535 × 65535 px)."""
    import cv2

    width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
    height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    frame = max(width, 0) * max(height, 0) * DECODED_CHANNELS_AT_LEAST
    limit = array_size_limit()
    if frame > limit:
        raise error(f"{path}: the video's {width}×{height} px frames would take {format_bytes(frame)} "
                    f"each, more than this host allows ({format_bytes(limit)}, half the available memory)")


def opencv_path(path: str | Path, error: type[ThinTactError] = ThinTactError) -> str:
    """``path`` as the text OpenCV's file functions take (``cv2.VideoCapture``).

    A name that is not valid UTF-8 (Python carries its bytes as surrogates) crashed OpenCV's
    reader with a segmentation fault; such a name is refused instead.

    Raises
    ------
    error
        Naming the path (its bytes escaped) and asking for another name.
    """
    text = str(path)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise error(f"{text.encode('utf-8', 'surrogateescape')!r}: the file name is not valid "
                    "UTF-8, which OpenCV cannot open; rename the file") from None
    return text


def read_image(path: str | Path, flags: int, error: type[ThinTactError] = ThinTactError,
               checked: bool = False) -> np.ndarray:
    """The image of ``path`` decoded by OpenCV with ``flags`` (``cv2.IMREAD_*``), after
    :func:`check_image_budget` on this file (skipped when the caller has ``checked`` it with
    the others it reads); OpenCV's channel order (B, G, R).

    The file's bytes are read by Python and decoded from memory (``cv2.imdecode``), so any
    name the file system holds works (OpenCV's own ``imread`` crashed on names that are not
    valid UTF-8), and a file larger on disk than the budget is refused before it is read.

    Raises
    ------
    error
        Refused by the budget, unreadable, or OpenCV cannot decode it.
    """
    import cv2

    p = Path(path)
    if not checked:
        check_image_budget([p], error)
    try:
        size = p.stat().st_size
        if size > array_size_limit():
            raise error(f"{p}: {format_bytes(size)} on disk, more than this host allows for one "
                        f"file ({format_bytes(array_size_limit())})")
        data = np.fromfile(p, np.uint8)
    except OSError as err:
        raise error(f"{p}: cannot read the image ({err.strerror or err})") from None
    img = cv2.imdecode(data, flags) if data.size else None
    if img is None:
        raise error(f"{p}: not a readable image")
    return img
