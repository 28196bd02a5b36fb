"""ThinTact virtual camera (plugin ``virtual``): the simulator behind the Camera API.

Camera component ``virtual``: ``factory(profile, settings)`` →
:class:`thintact_virtual.camera.VirtualCamera` (settings documented there). Scene injection
for calibration and tests: :func:`thintact_sdk.device.virtual_bench.get_scene_slot`.
"""

from __future__ import annotations

from typing import Any

from thintact_sdk import Component, hookimpl
from thintact_sdk.plugin_support import Profile, SceneSlot, get_scene_slot, signal_scale_dn
from thintact_virtual.camera import VirtualCamera

__all__ = ["SceneSlot", "VirtualCamera", "get_scene_slot", "signal_scale_dn"]


def _create(profile: Profile, settings: dict[str, Any] | None = None) -> VirtualCamera:
    return VirtualCamera(profile, settings or {})


@hookimpl
def thintact_cameras() -> list[Component]:
    return [
        Component(
            "virtual",
            _create,
            "simulated ThinTact camera (scene slot or scene library, noise, exposure, fps)",
            traits=("simulated",),
        )
    ]
