"""Bring your own matrices: system matrices calibrated elsewhere, in and out of a bundle.

Accepted files (``.npz`` or MATLAB ``.mat`` read with :func:`scipy.io.loadmat`):

* the four T2S matrices ``Po``, ``Qo``, ``Pc``, ``Qc``;
* FlatCam's one-term model ``Y = Φ_L X Φ_Rᵀ`` as ``Phi_L`` and ``Phi_R`` (also ``PhiL``/``PhiR``,
  ``phi_l``/``phi_r``): imported as ``Pc = Φ_L``, ``Qc = Φ_R`` and zero open matrices.

Each matrix is ``rows × cols`` (the same for every channel) or ``C × rows × cols``; ``P``-type
matrices are ``R × N`` (sensor rows × scene rows), ``Q``-type ``S × M``, in DN above black per
display unit per scene pixel. Shapes are checked against the profile with an error naming the
file, the array and the expected shape.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.safe_arrays import read_npz
from thintact_sdk.reconstruction.t2s import SystemMatrices

T2S_KEYS = ("Po", "Qo", "Pc", "Qc")
FLATCAM_KEYS = (("Phi_L", "Phi_R"), ("PhiL", "PhiR"), ("phi_l", "phi_r"))


_MAT_ITEM_BYTES = {"double": 8, "int64": 8, "uint64": 8, "single": 4, "int32": 4, "uint32": 4,
                   "int16": 2, "uint16": 2, "int8": 1, "uint8": 1, "logical": 1}
"""Bytes per element of the MATLAB classes a matrix may have (``scipy.io.whosmat`` names)."""


def _mat_damaged() -> tuple[type[BaseException], ...]:
    """What :func:`scipy.io.loadmat` / ``whosmat`` raise on a damaged or foreign file."""
    import struct
    import zlib

    from scipy.io.matlab import MatReadError

    return (MatReadError, OSError, ValueError, NotImplementedError, TypeError, IndexError,
            KeyError, EOFError, OverflowError, MemoryError, AttributeError, struct.error, zlib.error)


def _read_mat(path: Path) -> dict[str, np.ndarray]:
    """The known matrices of a MATLAB file (v4 to v7; v7.3 is HDF5 and refused): the variable
    headers are listed first (``whosmat``), every wanted variable must be a real numeric
    class and their declared sizes together within
    :func:`~thintact_sdk.formats.safe_arrays.array_size_limit`, and only then are those
    variables (and no others) read."""
    from scipy.io import loadmat, whosmat

    from thintact_sdk.formats.safe_arrays import array_size_limit, format_bytes

    known = set(T2S_KEYS) | {k for pair in FLATCAM_KEYS for k in pair}
    try:
        listed = whosmat(path)
    except _mat_damaged() as err:
        raise CalibrationError(f"cannot read {path}: {type(err).__name__}: {err}") from None
    found = [(name, shape, cls) for name, shape, cls in listed if name in known]
    if not found:
        raise CalibrationError(
            f"{path}: found arrays {', '.join(sorted(n for n, _, _ in listed)) or 'none'}; expected "
            "Po, Qo, Pc, Qc (T2S) or Phi_L, Phi_R (FlatCam)")
    total = 0
    for name, shape, cls in found:
        if cls not in _MAT_ITEM_BYTES:
            raise CalibrationError(f"{path}: {name} is a MATLAB {cls}, expected a real numeric array")
        total += int(np.prod(shape, dtype=np.float64)) * _MAT_ITEM_BYTES[cls]
    limit = array_size_limit()
    if total > limit:
        raise CalibrationError(f"{path}: the matrices declare {format_bytes(total)}, more than this "
                               f"host allows for one file ({format_bytes(limit)}); refused before reading")
    try:
        raw = loadmat(path, variable_names=[name for name, _, _ in found])
    except _mat_damaged() as err:
        raise CalibrationError(f"cannot read {path}: {type(err).__name__}: {err}") from None
    return {k: np.asarray(v) for k, v in raw.items() if k in known}


def _read(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise CalibrationError(f"matrices file not found: {path}")
    if path.suffix.lower() == ".mat":
        return _read_mat(path)
    try:
        if path.suffix.lower() == ".npz":
            return read_npz(path, what="matrices", error=CalibrationError)
    except (OSError, ValueError, NotImplementedError) as err:
        raise CalibrationError(f"cannot read {path}: {err}") from None
    raise CalibrationError(f"{path}: unknown matrices format {path.suffix!r}; use .npz or .mat")


MAX_PEAK = 1e15
"""Largest entry an imported system matrix may hold: the bundle stores float32 (to 3.4e38) and
the decoder forms products of the matrices over up to thousands of terms; ×1e300 matrices were
written as inf/NaN bundles."""
MIN_PEAK = 1e-30
"""Smallest largest entry: below float32's normal range the matrix stores as zeros."""


def _stack(path: Path, key: str, a: np.ndarray, want: tuple[int, int], channels: int) -> np.ndarray:
    arr = np.asarray(a)
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise CalibrationError(f"{path}: {key} must be a real numeric array, got {arr.dtype}")
    if arr.ndim == 2:
        arr = np.repeat(arr[None], channels, axis=0)
    if arr.ndim != 3 or arr.shape[1:] != want or arr.shape[0] != channels:
        raise CalibrationError(
            f"{path}: {key} is {'×'.join(map(str, a.shape))}, expected {want[0]}×{want[1]} or "
            f"{channels}×{want[0]}×{want[1]} for profile's sensor and scene grids"
        )
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{path}: {key} holds NaN or infinite values")
    peak = float(np.abs(arr).max()) if arr.size else 0.0
    if not MIN_PEAK <= peak <= MAX_PEAK:
        raise CalibrationError(
            f"{path}: {key} peaks at {peak:.3g}: a system matrix's largest entry must lie between "
            f"{MIN_PEAK:g} and {MAX_PEAK:g} (stored in float32, and its products must stay finite)")
    return arr


def import_matrices(path: str | os.PathLike[str], profile: Profile) -> SystemMatrices:
    """Read externally calibrated matrices for ``profile`` (see the module docstring).

    Raises
    ------
    CalibrationError
        Missing arrays, wrong shapes, non-finite values, unreadable file.
    """
    p = Path(path)
    arrays = _read(p)
    c = len(profile.sensor.channels)
    p_shape = (profile.sensor.rows, profile.scene.rows)
    q_shape = (profile.sensor.cols, profile.scene.cols)
    if all(k in arrays for k in T2S_KEYS):
        po, qo, pc, qc = (_stack(p, k, arrays[k], p_shape if k.startswith("P") else q_shape, c)
                          for k in T2S_KEYS)
        kind = "t2s"
    else:
        pair = next(((lk, rk) for lk, rk in FLATCAM_KEYS if lk in arrays and rk in arrays), None)
        if pair is None:
            raise CalibrationError(
                f"{p}: found arrays {', '.join(sorted(arrays)) or 'none'}; expected Po, Qo, Pc, Qc "
                "(T2S) or Phi_L, Phi_R (FlatCam)")
        pc = _stack(p, pair[0], arrays[pair[0]], p_shape, c)
        qc = _stack(p, pair[1], arrays[pair[1]], q_shape, c)
        po, qo = np.zeros_like(pc), np.zeros_like(qc)
        kind = "flatcam"
    return SystemMatrices(po, qo, pc, qc, {"source": "import", "imported_from": str(p.resolve()),
                                           "model": kind, "profile": profile.name,
                                           "profile_hash": profile.content_hash()})


def export_matrices(sm: SystemMatrices, path: str | os.PathLike[str]) -> Path:
    """Write ``Po, Qo, Pc, Qc`` (``C × rows × cols`` float64) as ``.npz`` or MATLAB ``.mat``."""
    p = Path(path)
    arrays = {k: np.asarray(getattr(sm, k), np.float64) for k in T2S_KEYS}
    p.parent.mkdir(parents=True, exist_ok=True)
    try:
        if p.suffix.lower() == ".mat":
            from scipy.io import savemat

            savemat(p, arrays, do_compression=True)
        elif p.suffix.lower() == ".npz":
            np.savez_compressed(p, **arrays)  # type: ignore[arg-type]
        else:
            raise CalibrationError(f"{p}: unknown matrices format {p.suffix!r}; use .npz or .mat")
    except OSError as err:
        raise CalibrationError(f"cannot write {p}: {err}") from None
    return p
