"""ThinTact UVC camera backend (plugin ``uvc``): V4L2 cameras, video files, image sequences.

Camera component ``uvc``: ``factory(profile, settings)`` →
:class:`thintact_uvc.camera.UvcCamera` (settings documented there and in docs/cameras.md).
Device lister ``uvc``: the ``/dev/video*`` section of ``thintact devices``
(:mod:`thintact_uvc.listing`).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from thintact_sdk import Component, hookimpl
from thintact_sdk.plugin_support import Profile
from thintact_uvc.camera import EndOfVideo, UvcCamera, UvcSettingWarning

__all__ = ["EndOfVideo", "UvcCamera", "UvcSettingWarning"]


def _create(profile: Profile, settings: dict[str, Any] | None = None) -> UvcCamera:
    return UvcCamera(profile, settings or {})


@hookimpl
def thintact_cameras() -> list[Component]:
    return [
        Component(
            "uvc",
            _create,
            "UVC/V4L2 camera, lossless video file or image sequence via OpenCV",
        )
    ]


def _device_lister(parser: argparse.ArgumentParser) -> Callable[[argparse.Namespace], Any]:
    from thintact_uvc.listing import device_lister

    return device_lister(parser)


@hookimpl
def thintact_device_listers() -> list[Component]:
    return [Component("uvc", _device_lister, "the /dev/video* (V4L2) nodes of this machine, "
                      "with their /dev/v4l/by-id names")]
