"""Typed ``camera.settings`` for camera plugins: one pydantic model per plugin.

Each camera plugin declares a :class:`CameraSettings` subclass listing its keys with types
and ranges and parses its settings with :func:`parse_camera_settings`; an unknown or
mistyped key is then the same :class:`~thintact_sdk.errors.CameraSettingsError` in every
plugin, naming the key (``camera.settings.fps``) and, for unknown keys, the known ones.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

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
