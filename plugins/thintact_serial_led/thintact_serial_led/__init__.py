"""ThinTact LED controller over a serial line (plugin ``serial-led``).

Light controller component ``serial-led``: ``factory(port, settings)`` →
:class:`thintact_serial_led.controller.SerialLedController`. The board's side of the
protocol is emulated by :mod:`thintact_serial_led.emulator` (``python -m
thintact_serial_led.emulator``). Protocol: docs/led-protocol.md.
"""

from __future__ import annotations

from typing import Any

from thintact_sdk import Component, hookimpl
from thintact_serial_led.controller import SerialLedController

__all__ = ["SerialLedController"]


def _create(port: str | None, settings: dict[str, Any] | None = None) -> SerialLedController:
    return SerialLedController(port, settings or {})


@hookimpl
def thintact_light_controllers() -> list[Component]:
    return [
        Component(
            "serial-led",
            _create,
            "10-LED board over a serial line (protocol v1: CRC-8, sequence numbers, retries)",
        )
    ]
