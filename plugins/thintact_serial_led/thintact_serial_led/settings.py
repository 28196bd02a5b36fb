"""The ``light.settings`` of the ``serial-led`` controller as a pydantic model.

Every key is typed strictly (``baudrate: "abc"``, ``led_count: .nan``, ``retries: true`` and
unknown keys are refused) and ranged; a bad value is one
:class:`~thintact_sdk.errors.InvalidValueError` naming ``light.settings.<key>``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from thintact_sdk.errors import InvalidValueError

MAX_LEDS = 256
"""Most LEDs one board may drive (the profile's ``light.intensities`` holds at most 256)."""


class SerialLedSettings(BaseModel):
    """``light.settings`` of ``serial-led``; every field has a default."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)

    baudrate: Annotated[int, Field(gt=0, le=12_000_000)] = 115200
    """Serial line speed, bit/s."""
    timeout_s: Annotated[float, Field(gt=0, le=60)] = 0.25
    """How long one attempt waits for the board's reply, s."""
    retries: Annotated[int, Field(ge=0, le=20)] = 3
    """Attempts after the first when a reply is missing or damaged."""
    led_count: Annotated[int, Field(ge=1, le=MAX_LEDS)] = 10
    """LEDs the board must report in its ``STA`` reply."""


def parse_settings(settings: Mapping[str, Any] | None) -> SerialLedSettings:
    """Validate ``settings`` (None: every default).

    Raises
    ------
    InvalidValueError
        ``settings`` is not a mapping, or a key is unknown, mistyped or out of range; one
        line per bad key, ``light.settings.<key>: <reason>``.
    """
    if settings is None:
        return SerialLedSettings()
    if not isinstance(settings, Mapping):
        raise InvalidValueError(f"light.settings of serial-led must be a mapping, not {type(settings).__name__}")
    try:
        return SerialLedSettings.model_validate(dict(settings))
    except ValidationError as err:
        known = ", ".join(SerialLedSettings.model_fields)
        lines = []
        for e in err.errors():
            key = ".".join(str(x) for x in e["loc"]) or "(all)"
            if e["type"] == "extra_forbidden":
                reason = f"unknown serial-led setting; known: {known}"
            else:
                reason = f"{e['msg']} (got {e.get('input')!r})"
            lines.append(f"light.settings.{key}: {reason}")
        raise InvalidValueError("invalid serial-led settings: " + "; ".join(lines)) from None
