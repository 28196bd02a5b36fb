"""Raw mosaics kept next to a recording's measurements (the ``raw`` frame extension, a core format:
``thintact record --raw`` writes it, the ``replay`` camera plugin reads it).

``thintact record --raw`` keeps each frame's raw camera data, as delivered, in
``raw/<index>.npy`` inside the ``thintact-recording/1`` directory and names it in that
frame's manifest entry (optional fields, CONTRACTS §3 allows them)::

    {"measurement": "measurements/000_frame0.npy", "raw": "raw/000000.npy",
     "pixel_format": "BayerRG12", "frame_id": 17, "timestamp_ns": ..., "exposure_us": ...}

Readers that do not know the extension still see a valid recording.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.recording import atomic_save_npy, read_array
from thintact_sdk.frames import RawFrame

RAW_FIELD = "raw"
PIXEL_FORMAT_FIELD = "pixel_format"


def save_raw_frame(root: Path, index: int, frame: RawFrame) -> dict[str, Any]:
    """Write ``frame.data`` atomically to ``root/raw/<index>.npy``.

    Returns
    -------
    dict
        The manifest fields to add to that frame's entry (``raw``, ``pixel_format``).
    """
    rel = f"{RAW_FIELD}/{index:06d}.npy"
    atomic_save_npy(Path(root) / rel, np.ascontiguousarray(frame.data))
    return {RAW_FIELD: rel, PIXEL_FORMAT_FIELD: frame.pixel_format}


def load_raw_data(root: Path, extra: dict[str, Any]) -> tuple[np.ndarray, str]:
    """The raw data and pixel format named by a frame's manifest fields.

    Raises
    ------
    RecordingError
        When the entry names no raw file, or the file is missing or truncated.
    """
    rel = extra.get(RAW_FIELD)
    if not isinstance(rel, str):
        raise RecordingError("frame has no 'raw' mosaic (record with --raw to keep them)")
    data = read_array(Path(root) / rel, is_scene=False)
    return data, str(extra.get(PIXEL_FORMAT_FIELD, "BayerRG16"))
