"""numpy arrays ↔ ``sensor_msgs/msg/Image`` messages (ROS 2 encodings, little endian).

Encodings used by a ThinTact log:

========================  ==========================================================
``bayer_rggb16`` etc.     raw Bayer mosaic, ``H × W`` uint16 DN (``…8`` for uint8)
``mono8`` / ``mono16``    raw monochrome frame
``rgb8`` / ``rgb16``      raw ``H × W × 3`` colour frame (``bayer_pattern: none``)
``32FC1`` / ``32FC3``     float32 ``H × W`` / ``H × W × 3`` (depth in mm; exact reconstruction)
``rgb8``                  reconstruction in display units clipped to [0, 1], times 255
========================  ==========================================================
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from thintact_sdk.errors import RecordingError

_BAYER_CODES = {"BayerRG": "rggb", "BayerBG": "bggr", "BayerGR": "grbg", "BayerGB": "gbrg"}
_FLOAT_CHANNELS = {1: "32FC1", 3: "32FC3"}
_DTYPE_OF: dict[str, type[np.generic]] = {"8": np.uint8, "16": np.uint16}


def header(stamp_ns: int, frame_id: str) -> dict[str, Any]:
    """A ``std_msgs/Header`` for a time in ns since the log's clock origin."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id}


def stamp_ns(header_msg: Any) -> int:
    """The time of a decoded ``std_msgs/Header`` in ns."""
    return int(header_msg.stamp.sec) * 1_000_000_000 + int(header_msg.stamp.nanosec)


def raw_encoding(data: np.ndarray, pixel_format: str) -> str:
    """The ROS image encoding of a camera frame.

    Parameters
    ----------
    data
        ``H × W`` or ``H × W × C`` array as the camera delivered it.
    pixel_format
        GenICam pixel format name of the frame (``"BayerRG12"``, ``"Mono8"``, ``"RGB8"``).

    Raises
    ------
    RecordingError
        For a dtype/shape without a ROS encoding.
    """
    channels = 1 if data.ndim == 2 else data.shape[2]
    if data.dtype == np.float32 and channels in _FLOAT_CHANNELS:
        return _FLOAT_CHANNELS[channels]
    bits = {np.dtype(np.uint8): "8", np.dtype(np.uint16): "16"}.get(data.dtype)
    if bits is not None:
        if channels == 1:
            code = _BAYER_CODES.get(pixel_format[:7])
            return f"bayer_{code}{bits}" if code else f"mono{bits}"
        if channels == 3:
            return f"rgb{bits}"
    raise RecordingError(
        f"frame of pixel format {pixel_format!r}, shape {data.shape} and dtype {data.dtype} "
        "has no ROS image encoding (uint8/uint16 mono, Bayer or RGB, or float32 1/3 channels)"
    )


def pixel_format_of(encoding: str) -> str:
    """The GenICam pixel format a raw image of ``encoding`` is replayed as."""
    if encoding.startswith("bayer_"):
        code, bits = encoding[6:10], encoding[10:]
        name = {v: k for k, v in _BAYER_CODES.items()}[code]
        return f"{name}{bits}"
    if encoding.startswith("mono"):
        return f"Mono{encoding[4:]}"
    if encoding.startswith("rgb"):
        return f"RGB{encoding[3:]}"
    return {"32FC1": "Mono32f", "32FC3": "RGB32f"}[encoding]


def image_message(array: np.ndarray, encoding: str, stamp: int, frame_id: str) -> dict[str, Any]:
    """A ``sensor_msgs/msg/Image`` (as a dict for the ROS 2 encoder) holding ``array``.

    ``array`` must already have the dtype of ``encoding``; it is written little endian.
    """
    data = np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("<"))
    height, width = int(data.shape[0]), int(data.shape[1])
    return {
        "header": header(stamp, frame_id),
        "height": height,
        "width": width,
        "encoding": encoding,
        "is_bigendian": 0,
        "step": int(data.nbytes // max(height, 1)),
        "data": data.tobytes(),
    }


RECONSTRUCTION_ENCODINGS = ("rgb8", "32FC3")


def check_reconstruction_encoding(encoding: str) -> None:
    """Raise RecordingError unless ``encoding`` is one of :data:`RECONSTRUCTION_ENCODINGS`."""
    if encoding not in RECONSTRUCTION_ENCODINGS:
        raise RecordingError(
            f"reconstruction encoding must be 'rgb8' or '32FC3', not {encoding!r}")


def reconstruction_array(image: np.ndarray, encoding: str) -> np.ndarray:
    """The reconstruction (``N × M × 3`` float32 display units) as stored for ``encoding``."""
    if encoding == "rgb8":
        return np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)
    check_reconstruction_encoding(encoding)
    return np.asarray(image, np.float32)


def decode_image(msg: Any) -> np.ndarray:
    """A decoded ``sensor_msgs/msg/Image`` as a numpy array.

    Returns
    -------
    np.ndarray
        ``H × W`` or ``H × W × C`` in the encoding's dtype (uint8, uint16 or float32).

    Raises
    ------
    RecordingError
        For an encoding a ThinTact log does not use, or data of the wrong length.
    """
    enc = str(msg.encoding)
    dtype: type[np.generic] | None
    if enc.startswith("bayer_"):
        dtype, channels = _DTYPE_OF.get(enc[10:]), 1
    elif enc.startswith("mono"):
        dtype, channels = _DTYPE_OF.get(enc[4:]), 1
    elif enc.startswith("rgb"):
        dtype, channels = _DTYPE_OF.get(enc[3:]), 3
    elif enc in ("32FC1", "32FC3"):
        dtype, channels = np.float32, int(enc[-1])
    else:
        dtype, channels = None, 0
    if dtype is None:
        raise RecordingError(f"image encoding {enc!r} is not one a ThinTact log uses")
    base = np.dtype(dtype)
    flat = np.frombuffer(bytes(msg.data),
                         dtype=base.newbyteorder(">") if msg.is_bigendian else base.newbyteorder("<"))
    shape = (int(msg.height), int(msg.width)) + ((channels,) if channels > 1 else ())
    if flat.size != int(np.prod(shape)):
        raise RecordingError(
            f"image of {msg.height}×{msg.width} {enc} holds {len(msg.data)} bytes, "
            f"expected {int(np.prod(shape)) * np.dtype(dtype).itemsize}"
        )
    return flat.reshape(shape).astype(dtype, copy=False)


# -- raw frames that common viewers display ------------------------------------------------
VIEWER_ENCODINGS = ("mono8", "mono16", "rgb8", "bayer_rggb8", "bayer_bggr8", "bayer_grbg8",
                    "bayer_gbrg8")
"""Raw encodings that open-source Foxglove / Lichtblick decode; other raw encodings
(``bayer_*16``, ``rgb16``) get a ``/thintact/raw_preview`` channel beside the raw."""


def bit_depth(pixel_format: str, dtype: np.dtype[Any]) -> int:
    """Significant bits of a frame: the number in its pixel format, at most the dtype's width.

    ``BayerRG12`` → 12, ``Mono10`` → 10, ``RGB8`` → 8; a name without a number (or one
    larger than the dtype) → the dtype's width (8 or 16).
    """
    width = 8 * np.dtype(dtype).itemsize
    digits = re.search(r"(\d+)", pixel_format)
    bits = int(digits.group(1)) if digits else width
    return bits if 0 < bits <= width else width


def msb_align(data: np.ndarray, bits: int, what: str) -> tuple[np.ndarray, int]:
    """``data`` shifted left so its ``bits`` significant bits fill the dtype; ``(array, shift)``.

    A uint16 frame of 12-bit values becomes ``value << 4`` (a viewer that keeps the high
    byte, or scales 0..65535, shows it at full range); readers shift right by ``shift``
    (recorded in the log) to recover the exact DN. uint8 and float frames: shift 0.

    Raises
    ------
    RecordingError
        When a value does not fit in ``bits`` (the pixel format understates the data).
    """
    if data.dtype != np.uint16 or bits >= 16:
        return data, 0
    shift = 16 - bits
    if int(data.max(initial=0)) >> bits:
        raise RecordingError(
            f"{what}: value {int(data.max())} does not fit the {bits} bits its pixel format "
            "names; say the right pixel format (e.g. camera.settings.pixel_format: BayerRG16)")
    return np.left_shift(data, shift), shift


def preview_rgb8(data: np.ndarray, pixel_format: str, bits: int) -> np.ndarray:
    """An ``rgb8`` preview of a raw frame (DN scaled so ``2**bits - 1`` is 255).

    Bayer mosaics are binned to half resolution (R, mean G, B of each 2 × 2 cell, no
    interpolation); mono frames are repeated in three channels; RGB frames are scaled.
    Integer mosaics of 8 bits or more take an integer path (the top 8 bits, truncated: at
    most 1 below the rounded value).
    """
    from thintact_sdk.pixels.bayer import _site_offsets, bin_bayer, pattern_from_pixel_format

    pattern = pattern_from_pixel_format(pixel_format) if data.ndim == 2 else None
    even = data.ndim == 2 and data.shape[0] % 2 == 0 and data.shape[1] % 2 == 0
    if pattern is not None and even and data.dtype.kind == "u" and bits >= 8:
        (rr, rc), (g1r, g1c), (g2r, g2c), (br, bc) = _site_offsets(pattern)
        shift = bits - 8
        out = np.empty((data.shape[0] // 2, data.shape[1] // 2, 3), np.uint8)
        out[..., 0] = data[rr::2, rc::2] >> shift
        g = data[g1r::2, g1c::2].astype(np.uint32) + data[g2r::2, g2c::2]
        out[..., 1] = g >> (shift + 1)
        out[..., 2] = data[br::2, bc::2] >> shift
        return out
    if pattern is not None and even:
        rgb = bin_bayer(data, pattern)
    elif data.ndim == 2:
        rgb = np.repeat(data[..., None].astype(np.float32), 3, axis=2)
    else:
        rgb = data[..., :3].astype(np.float32)
    scale = np.float32(255.0 / float(2**bits - 1))
    return np.clip(np.rint(rgb * scale), 0, 255).astype(np.uint8)


def needs_preview(encoding: str) -> bool:
    """True for a raw integer encoding that open-source viewers cannot decode."""
    return encoding not in VIEWER_ENCODINGS and not encoding.startswith("32FC")
