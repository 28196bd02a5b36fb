"""ThinTact GenICam camera backend (plugin ``genicam``), through harvesters and GenTL.

Camera component ``genicam``: ``factory(profile, settings)`` →
:class:`thintact_genicam.camera.GenICamCamera` (settings documented there and in
docs/cameras.md). :mod:`thintact_genicam.producers` finds producers and lists devices.

Device lister ``genicam`` (the GenICam section of ``thintact devices``): ``factory(parser)``
adds ``--cti`` and ``--no-profiles`` and returns :func:`thintact_genicam.listing.list_section`.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
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


def _device_lister(parser: argparse.ArgumentParser) -> Callable[[argparse.Namespace], Any]:
    from thintact_genicam.listing import device_lister

    return device_lister(parser)


@hookimpl
def thintact_device_listers() -> list[Component]:
    return [Component("genicam", _device_lister,
                      "the GenTL producers (.cti files) named by profiles, --cti and "
                      "GENICAM_GENTL64_PATH, and the devices each offers, via harvesters")]
