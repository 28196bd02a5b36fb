"""Reading the ``.npz`` files of a calibration bundle strictly.

Every array is checked to be a finite float (or integer) array; the archive is read with
:func:`thintact_sdk.formats.safe_arrays.read_npz` (magic bytes, each member's header before its data,
no pickles, declared sizes bounded by the memory there is), and every way a damaged file can
fail (truncated, random bytes, a missing or non-numeric member, a bad or too deeply nested
``meta_json``) becomes one :class:`~thintact_sdk.errors.CalibrationError` naming the file
and the member.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats import safe_json
from thintact_sdk.formats.safe_arrays import is_npz
from thintact_sdk.formats.safe_arrays import read_npz as read_untrusted_npz


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
    if not is_npz(path):
        raise CalibrationError(f"{path} is not a calibration bundle file: not an .npz archive "
                               f"(expected the {what} written by the calibration)")
    arrays = read_untrusted_npz(path, what=what, error=CalibrationError, members=keys,
                                optional=("meta_json",), kinds={"meta_json": "U"})
    meta_text = str(arrays.pop("meta_json")) if "meta_json" in arrays else "{}"
    for k, arr in arrays.items():
        if arr.dtype.kind not in "fiu" or arr.size == 0:
            raise CalibrationError(f"{path}: array {k} has dtype {arr.dtype} and {arr.size} "
                                   "values; expected a non-empty float array")
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        if bad:
            raise CalibrationError(f"{path}: array {k} holds {bad} NaN/Inf value(s)")
    meta = safe_json.loads(meta_text, f"{path}: meta_json", CalibrationError)
    if not isinstance(meta, dict):
        raise CalibrationError(f"{path}: meta_json must be a JSON object")
    return arrays, meta
