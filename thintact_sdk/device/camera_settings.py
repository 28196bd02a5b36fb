"""Typed ``camera.settings`` for camera plugins: one pydantic model per plugin.

Each camera plugin declares a :class:`CameraSettings` subclass listing its keys with types
and ranges and parses its settings with :func:`parse_camera_settings`; an unknown or
mistyped key is then the same :class:`~thintact_sdk.errors.CameraSettingsError` in every
plugin, naming the key (``camera.settings.fps``) and, for unknown keys, the known ones.
"""

from __future__ import annotations

from collections.abc import Mapping
from fractions import Fraction
from typing import Any, Literal, TypeVar

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictFloat,
    StrictInt,
    StrictStr,
    ValidationError,
)

from thintact_sdk.errors import CameraSettingsError


class CameraSettings(BaseModel):
    """Base of every camera plugin's settings model: unknown keys are refused."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


SettingsT = TypeVar("SettingsT", bound=CameraSettings)


def parse_camera_settings(model: type[SettingsT], settings: Mapping[str, Any], plugin: str) -> SettingsT:
    """Validate ``settings`` against ``model``.

    Raises
    ------
    CameraSettingsError
        One line per bad key: ``camera.settings.<key>: <reason>``, unknown keys with the
        list of known ones.
    """
    try:
        return model.model_validate(dict(settings))
    except ValidationError as err:
        known = ", ".join(sorted(model.model_fields))
        lines = []
        for e in err.errors():
            key = ".".join(str(x) for x in e["loc"]) or "(all)"
            if e["type"] == "extra_forbidden":
                reason = f"unknown {plugin} camera setting; known: {known}"
            elif e["type"] == "missing":
                reason = "required"
            else:
                reason = f"{e['msg']} (got {e.get('input')!r})"
            lines.append(f"  - camera.settings.{key}: {reason}")
        raise CameraSettingsError(f"invalid {plugin} camera settings:\n" + "\n".join(lines)) from None


# -- frame geometry: crop, transpose, flip, rotate (lens sensors, docs/lens-sensors.md) ------
Margin = StrictInt | StrictFloat | StrictStr
"""A crop margin: an int is pixels, a float in [0, 0.5) or a ``"1/7"`` string a fraction of
the side it is taken from (rounded down to whole pixels, as vendor SDKs do)."""


class CropSettings(BaseModel):
    """Margins removed from each side of the delivered frame (``camera.settings.crop``)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    top: Margin = 0
    bottom: Margin = 0
    left: Margin = 0
    right: Margin = 0


class FrameGeometrySettings(CameraSettings):
    """Settings that reshape every delivered frame before binning, in this order:

    ``crop`` (margins of the frame as the device delivers it), ``transpose`` (rows ↔
    columns), ``flip`` (``vertical``: rows reversed, ``horizontal``: columns reversed,
    ``both``), ``rotate`` (degrees counter-clockwise: 0, 90, 180, 270). On a Bayer mosaic
    an odd crop or any rotation moves the colour sites: give the profile's
    ``bayer_pattern`` as the reshaped frame has it.
    """

    crop: CropSettings | None = None
    transpose: bool = Field(default=False, strict=True)
    flip: Literal["none", "vertical", "horizontal", "both"] = "none"
    rotate: Literal[0, 90, 180, 270] = 0


def margin_px(value: int | float | str, size: int, key: str) -> int:
    """Pixels of a crop margin ``value`` on a side of ``size`` pixels.

    Raises
    ------
    CameraSettingsError
        A negative pixel count, or a fraction outside [0, 0.5) or not ``"a/b"``.
    """
    if isinstance(value, int):
        if value < 0:
            raise CameraSettingsError(f"camera.settings.crop.{key}: {value} pixels is negative")
        return value
    try:
        frac = Fraction(value) if isinstance(value, str) else Fraction(str(value))
    except (ValueError, ZeroDivisionError):
        raise CameraSettingsError(
            f"camera.settings.crop.{key}: {value!r} is neither pixels (an integer) nor a "
            "fraction such as 0.15 or '1/7'") from None
    if not 0 <= frac < Fraction(1, 2):
        raise CameraSettingsError(
            f"camera.settings.crop.{key}: fraction {value!r} must be in [0, 0.5) "
            "(pixels are integers)")
    return int(frac * size)


def crop_box(height: int, width: int, crop: CropSettings) -> tuple[int, int, int, int]:
    """``(top, bottom, left, right)`` pixels of ``crop`` on an ``height × width`` frame.

    Raises
    ------
    CameraSettingsError
        When the margins leave no pixel.
    """
    top, bottom = margin_px(crop.top, height, "top"), margin_px(crop.bottom, height, "bottom")
    left, right = margin_px(crop.left, width, "left"), margin_px(crop.right, width, "right")
    if top + bottom >= height or left + right >= width:
        raise CameraSettingsError(
            f"camera.settings.crop: margins top {top}, bottom {bottom}, left {left}, right "
            f"{right} px leave nothing of a {height}×{width} frame")
    return top, bottom, left, right


def apply_geometry(frame: np.ndarray, geometry: FrameGeometrySettings) -> np.ndarray:
    """``frame`` (``H × W`` or ``H × W × C``) cropped, transposed, flipped and rotated.

    Returns a C-contiguous array (the input itself when nothing is set).
    """
    out = frame
    if geometry.crop is not None:
        t, b, left, right = crop_box(out.shape[0], out.shape[1], geometry.crop)
        out = out[t:out.shape[0] - b, left:out.shape[1] - right]
    if geometry.transpose:
        out = out.swapaxes(0, 1)
    if geometry.flip in ("vertical", "both"):
        out = out[::-1]
    if geometry.flip in ("horizontal", "both"):
        out = out[:, ::-1]
    if geometry.rotate:
        out = np.rot90(out, geometry.rotate // 90)
    return out if out is frame else np.ascontiguousarray(out)
