"""A camera's declared tone curve, undone before anything bins or decodes a frame.

Cameras that deliver JPEG/MJPEG (most UVC cameras) or run an ISP encode the linear signal
with a tone curve before quantising it. Every decoder assumes linear DN (the contract's
``DN = black + g·irradiance``), so a profile declares the curve in ``sensor.tone_curve`` and
:func:`linearize` undoes it: in :func:`thintact_sdk.device.cameras.to_measurement` (before Bayer
binning, so that the two greens are averaged in linear light) and in
:meth:`thintact_sdk.formats.recording.Recording.measurement` for tone-mapped recorded frames.

Kinds (``FS = noise.saturation_dn − noise.black_level_dn``, ``b = noise.black_level_dn``,
``v`` the delivered DN, ``L`` the linear DN; every curve keeps ``b`` and ``b + FS`` fixed):

``gamma``
    ``v − b = FS·((L − b)/FS)^gamma``, the contract's ``sensor_gamma`` effect with the same
    parameter (a display-encoding camera has gamma ≈ 1/2.2 ≈ 0.45). Undone as
    ``L = b + FS·((v − b)/FS)^(1/gamma)`` (sign kept below black so noise stays symmetric).
``srgb``
    IEC 61966-2-1 (sRGB) encoding of ``(L − b)/FS``.
``table``
    ``values`` (inline) or ``file`` (``.npy``, or ``.csv``/``.txt`` of numbers): the linear DN
    for each delivered code ``0 … 2^bits − 1``, black level included. Finite, non-decreasing,
    exactly ``2^bits`` entries.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal, Protocol, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from thintact_sdk.errors import InvalidValueError, ProfileError
from thintact_sdk.formats.safe_arrays import read_npy


class _ProfileLike(Protocol):
    """What this module reads of a device profile (:class:`thintact_sdk.formats.profiles.Profile` is
    one). A structural type, so that ``tone_curve`` does not import ``profile`` (which
    validates its ``sensor.tone_curve`` with :class:`ToneCurveSpec`): no import cycle."""

    name: str
    _source: Path | None

    @property
    def sensor(self) -> Any: ...
    @property
    def noise(self) -> Any: ...
    def resolve_path(self, path: str | Path) -> Path: ...
    def model_copy(self, *, update: dict[str, Any] | None = None, deep: bool = False) -> Any: ...


ProfileT = TypeVar("ProfileT", bound=_ProfileLike)

__all__ = ["ToneCurveSpec", "check_table_file", "encode", "has_tone_curve", "inline_table", "linear_table", "linearize"]

FIELD = "sensor.tone_curve"
MAX_TABLE_BITS = 16


class ToneCurveSpec(BaseModel):
    """``sensor.tone_curve``: how the camera's delivered DN relate to linear DN."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["gamma", "srgb", "table"] = Field(description="gamma, srgb or table")
    gamma: Annotated[float, Field(gt=0.05, lt=20, allow_inf_nan=False)] | None = Field(
        default=None, description="kind gamma: v − b = FS·((L − b)/FS)^gamma (as sensor_gamma)"
    )
    bits: Annotated[int, Field(strict=True, ge=1, le=MAX_TABLE_BITS)] | None = Field(
        default=None, description="kind table: code depth of the delivered frames (2^bits entries)"
    )
    values: list[float] | None = Field(
        default=None, description="kind table: linear DN of each delivered code, inline"
    )
    file: str | None = Field(
        default=None, description="kind table: .npy/.csv/.txt with the same numbers (relative "
        "to the profile file)"
    )

    @model_validator(mode="after")
    def _parameters_of_kind(self) -> ToneCurveSpec:
        if self.kind == "gamma" and self.gamma is None:
            raise ValueError("kind 'gamma' needs 'gamma' (the exponent of the sensor_gamma effect, "
                             "e.g. 0.45 for a display-encoding camera)")
        if self.kind != "gamma" and self.gamma is not None:
            raise ValueError(f"'gamma' belongs to kind 'gamma', not {self.kind!r}")
        if self.kind == "table":
            if self.bits is None:
                raise ValueError("kind 'table' needs 'bits' (8 for JPEG/MJPEG frames)")
            if (self.values is None) == (self.file is None):
                raise ValueError("kind 'table' needs exactly one of 'values' (inline) or 'file'")
            if self.values is not None:
                check_table(np.asarray(self.values, dtype=np.float64), self.bits, "values")
        elif self.values is not None or self.file is not None or self.bits is not None:
            raise ValueError(f"'values', 'file' and 'bits' belong to kind 'table', not {self.kind!r}")
        return self


def check_table(table: np.ndarray, bits: int, where: str) -> None:
    """Refuse a table that is not 1-D, finite, non-decreasing with ``2^bits`` entries.

    Raises
    ------
    ValueError
        The message names ``where`` (``values`` or the file) and the first bad entry.
    """
    need = 2**bits
    if table.ndim != 1 or table.size != need:
        raise ValueError(f"{where}: {table.size} entr{'y' if table.size == 1 else 'ies'} (shape "
                         f"{table.shape}), a {bits}-bit table needs exactly {need}")
    bad = ~np.isfinite(table)
    if bad.any():
        raise ValueError(f"{where}: entry {int(np.argmax(bad))} is NaN/Inf")
    drops = np.flatnonzero(np.diff(table) < 0)
    if drops.size:
        k = int(drops[0]) + 1
        raise ValueError(f"{where}: not monotonic, entry {k} ({table[k]:g}) is below entry {k - 1} "
                         f"({table[k - 1]:g})")
    if table[-1] <= table[0]:
        raise ValueError(f"{where}: constant table (every code maps to {table[0]:g} DN)")


def _spec(profile: ProfileT) -> ToneCurveSpec | None:
    spec = getattr(profile.sensor, "tone_curve", None)
    return spec if isinstance(spec, ToneCurveSpec) else None


def has_tone_curve(profile: ProfileT) -> bool:
    """Whether the profile declares ``sensor.tone_curve``."""
    return _spec(profile) is not None


def _read_table_file(path: Path, bits: int) -> np.ndarray:
    if not path.is_file():
        raise ProfileError(f"{FIELD}.file: {path} not found")
    try:
        if path.suffix.lower() == ".npy":
            table = read_npy(path, what=f"{FIELD}.file", error=ProfileError, kinds="uif")
        else:
            table = np.loadtxt(path, delimiter="," if path.suffix.lower() == ".csv" else None, ndmin=1)
    except (ValueError, OSError, EOFError) as err:
        raise ProfileError(f"{FIELD}.file: cannot read {path}: {err}") from None
    if not isinstance(table, np.ndarray) or table.dtype.kind not in "uif":
        raise ProfileError(f"{FIELD}.file: {path} does not hold numbers")
    table = table.astype(np.float64).ravel() if table.ndim == 2 and 1 in table.shape else table
    try:
        check_table(np.asarray(table, np.float64), bits, f"{FIELD}.file {path}")
    except ValueError as err:
        raise ProfileError(str(err)) from None
    return np.asarray(table, np.float64)


def check_table_file(profile: ProfileT) -> None:
    """Read and check a ``kind: table`` curve's ``file`` (at profile load, so that a bad file is
    refused before any frame). No-op for other curves.

    Raises
    ------
    ProfileError
        Naming ``sensor.tone_curve.file``: missing, unreadable, wrong length, NaN/Inf, not
        monotonic.
    """
    spec = _spec(profile)
    if spec is not None and spec.kind == "table" and spec.file is not None:
        _table(profile)


def inline_table(profile: ProfileT) -> ProfileT:
    """``profile`` with a table curve's ``file`` replaced by its ``values`` (for a recording's
    self-contained ``profile.json``); the profile itself when there is nothing to inline."""
    spec = _spec(profile)
    if spec is None or spec.kind != "table" or spec.file is None:
        return profile
    values = [float(v) for v in _table(profile)]
    out = profile.model_copy(deep=True)
    out.sensor.tone_curve = spec.model_copy(update={"values": values, "file": None})
    out._source = profile._source
    return out


def _inverse_curve(spec: ToneCurveSpec, v: np.ndarray) -> np.ndarray:
    """Normalised delivered ``v`` (``(DN − b)/FS``) → normalised linear signal."""
    s, a = np.sign(v), np.abs(v)
    if spec.kind == "gamma":
        assert spec.gamma is not None
        return s * a ** (1.0 / spec.gamma)
    return s * np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)


def _table(profile: ProfileT) -> np.ndarray:
    spec = _spec(profile)
    assert spec is not None and spec.kind == "table" and spec.bits is not None
    if spec.values is not None:
        return np.asarray(spec.values, np.float64)
    assert spec.file is not None
    return _read_table_file(profile.resolve_path(spec.file), spec.bits)


@lru_cache(maxsize=16)
def _code_table(kind: str, gamma: float | None, black: float, full: float, n: int) -> np.ndarray:
    spec = ToneCurveSpec(kind=kind, gamma=gamma)  # type: ignore[arg-type]
    codes = np.arange(n, dtype=np.float64)
    return (black + full * _inverse_curve(spec, (codes - black) / full)).astype(np.float32)


def linear_table(profile: ProfileT, codes: int) -> np.ndarray:
    """Linear DN (float32) of every delivered integer code ``0 … codes − 1``.

    Raises
    ------
    ProfileError
        When the profile declares no tone curve, or a table file is missing or invalid.
    """
    spec = _spec(profile)
    if spec is None:
        raise ProfileError(f"profile {profile.name!r} declares no {FIELD}")
    if spec.kind == "table":
        table = _table(profile).astype(np.float32)
        return table if codes <= table.size else np.concatenate(
            [table, np.full(codes - table.size, table[-1], np.float32)])[:codes]
    nz = profile.noise
    return _code_table(spec.kind, spec.gamma, float(nz.black_level_dn),
                       float(nz.saturation_dn - nz.black_level_dn), codes)


def linearize(data: np.ndarray, profile: ProfileT, what: str = "frame") -> np.ndarray:
    """Undo the profile's ``sensor.tone_curve`` on delivered DN.

    Parameters
    ----------
    data
        Delivered frame, any shape, integer or float DN (as the camera encoded them).
    profile
        Supplies the curve and ``noise.black_level_dn`` / ``noise.saturation_dn``.
    what
        Names the frame in errors.

    Returns
    -------
    numpy.ndarray
        Same shape, float32 linear DN (black level included); ``data`` itself when the
        profile declares no curve.

    Raises
    ------
    InvalidValueError
        An integer code beyond a table's ``2^bits − 1`` (the frame is deeper than declared).
    ProfileError
        A table file is missing or invalid (the field is named).
    """
    spec = _spec(profile)
    if spec is None:
        return data
    if spec.kind == "table":
        assert spec.bits is not None
        top = 2**spec.bits - 1
        hi = float(data.max()) if data.size else 0.0
        if hi > top:
            raise InvalidValueError(
                f"{what}: delivered value {hi:g} exceeds {top}, the largest code of the "
                f"{spec.bits}-bit {FIELD} table; declare the frames' real bit depth"
            )
        table = linear_table(profile, top + 1)
        if data.dtype.kind == "u":
            return table[data]
        return np.interp(data, np.arange(top + 1), table).astype(np.float32)
    if data.dtype.kind == "u" and data.dtype.itemsize <= 2:
        n = 256 if data.dtype.itemsize == 1 else 65536
        return linear_table(profile, n)[data]
    nz = profile.noise
    full = float(nz.saturation_dn - nz.black_level_dn)
    norm = (np.asarray(data, np.float64) - nz.black_level_dn) / full
    return (nz.black_level_dn + full * _inverse_curve(spec, norm)).astype(np.float32)


def encode(linear: np.ndarray, profile: ProfileT) -> np.ndarray:
    """The declared curve applied to linear DN (float64 delivered DN; for simulation and tests).

    ``linearize(encode(x)) ≈ x``; a table is inverted by interpolation.
    """
    spec = _spec(profile)
    if spec is None:
        return np.asarray(linear, np.float64)
    nz = profile.noise
    if spec.kind == "table":
        assert spec.bits is not None
        table = linear_table(profile, 2**spec.bits).astype(np.float64)
        return np.interp(linear, table, np.arange(table.size, dtype=np.float64))
    full = float(nz.saturation_dn - nz.black_level_dn)
    u = (np.asarray(linear, np.float64) - nz.black_level_dn) / full
    s, a = np.sign(u), np.abs(u)
    if spec.kind == "gamma":
        assert spec.gamma is not None
        enc = s * a**spec.gamma
    else:
        enc = s * np.where(a <= 0.0031308, 12.92 * a, 1.055 * a ** (1 / 2.4) - 0.055)
    return nz.black_level_dn + full * enc
