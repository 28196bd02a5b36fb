"""Reading the ``.npz`` files of a calibration bundle strictly.

Every array is checked to be a finite float (or integer) array, the archive is opened with
``allow_pickle=False`` only after its magic bytes say it is a zip archive, and every way a
damaged file can fail (truncated, random bytes, a missing or non-numeric member, a bad
``meta_json``) becomes one :class:`~thintact_sdk.errors.CalibrationError` naming the file
and the member.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import CalibrationError

_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


def read_npz(path: Path, what: str, keys: tuple[str, ...]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The arrays ``keys`` and the ``meta_json`` dict of a bundle ``.npz`` file.

    Parameters
    ----------
    path
        The ``.npz`` file.
    what
        What the file holds, for messages (``"system matrices"``, ``"filter"``).
    keys
        Members that must be present; each must be a finite numeric array.

    Raises
    ------
    CalibrationError
        Naming ``path`` and the member, when the file is missing, not an ``.npz`` archive,
        truncated, or holds a missing, non-numeric or non-finite array or a bad ``meta_json``.
    """
    if not path.is_file():
        raise CalibrationError(f"{what} file not found: {path}")
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as err:
        raise CalibrationError(f"cannot read {what} {path}: {err.strerror or err}") from None
    if head not in _ZIP_MAGIC:
        raise CalibrationError(f"{path} is not a calibration bundle file: not an .npz archive "
                               f"(expected the {what} written by the calibration)")
    arrays: dict[str, np.ndarray] = {}
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in keys if k not in z.files]
            if missing:
                raise CalibrationError(f"{path}: missing arrays {', '.join(missing)}")
            for k in keys:
                arrays[k] = z[k]
            meta_text = str(z["meta_json"]) if "meta_json" in z.files else "{}"
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error,
            NotImplementedError) as err:
        raise CalibrationError(f"{path} is not a readable calibration bundle file "
                               f"(truncated or damaged {what}): {err}") from None
    for k, arr in arrays.items():
        if arr.dtype.kind not in "fiu" or arr.size == 0:
            raise CalibrationError(f"{path}: array {k} has dtype {arr.dtype} and {arr.size} "
                                   "values; expected a non-empty float array")
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        if bad:
            raise CalibrationError(f"{path}: array {k} holds {bad} NaN/Inf value(s)")
    try:
        meta = json.loads(meta_text)
    except json.JSONDecodeError as err:
        raise CalibrationError(f"{path}: meta_json is not valid JSON ({err})") from None
    if not isinstance(meta, dict):
        raise CalibrationError(f"{path}: meta_json must be a JSON object")
    return arrays, meta
