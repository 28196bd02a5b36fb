"""ThinTact GenICam camera backend (plugin ``genicam``), through harvesters and GenTL.

Camera component ``genicam``: ``factory(profile, settings)`` →
:class:`thintact_genicam.camera.GenICamCamera` (settings documented there and in
docs/cameras.md). :mod:`thintact_genicam.producers` finds producers and lists devices.
"""

from __future__ import annotations

from typing import Any

from thintact_genicam.camera import GenICamCamera, GenICamSettingWarning
from thintact_sdk import Component, hookimpl
from thintact_sdk.plugin_support import Profile

__all__ = ["GenICamCamera", "GenICamSettingWarning"]


def _create(profile: Profile, settings: dict[str, Any] | None = None) -> GenICamCamera:
    return GenICamCamera(profile, settings or {})


@hookimpl
def thintact_cameras() -> list[Component]:
    return [
        Component(
            "genicam",
            _create,
            "GenICam/GenTL camera via harvesters (settings.cti names the vendor's producer)",
        )
    ]


def _list_producer_devices(source: str) -> list[dict[str, Any]]:
    from thintact_genicam.producers import list_devices

    return list_devices(source)


@hookimpl
def thintact_device_listers() -> list[Component]:
    return [Component("genicam", _list_producer_devices,
                      "the devices a GenTL producer (.cti file) offers, via harvesters")]
