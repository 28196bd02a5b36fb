"""ThinTact calibration displays (plugin ``thintact-displays``).

Display components (``factory(profile, settings) -> thintact_sdk.interfaces.Display``):

``pygame``
    A borderless full-screen window on display ``profile.display.display_index`` (SDL);
    the scene is drawn at ``profile.display.origin_px``, one panel pixel per scene pixel
    (or an integer block when the scene pitch is a multiple of the panel pitch), black
    elsewhere. See :mod:`thintact_displays.pygame_display`.
``virtual``
    Puts the scene in the virtual sensor's scene slot
    (``thintact_sdk.device.virtual_bench.get_scene_slot(key).set(scene)``), so the virtual camera
    renders it. See :mod:`thintact_displays.virtual_display`.
"""

from __future__ import annotations

from typing import Any

from thintact_displays.layout import PanelLayout, panel_layout, scene_to_rgb8
from thintact_displays.pygame_display import PygameDisplay
from thintact_displays.virtual_display import VirtualDisplay
from thintact_sdk import Component, hookimpl
from thintact_sdk.plugin_support import Profile

__all__ = ["PanelLayout", "PygameDisplay", "VirtualDisplay", "panel_layout", "scene_to_rgb8"]


def _pygame(profile: Profile, settings: dict[str, Any] | None = None) -> PygameDisplay:
    return PygameDisplay(profile, settings or {})


def _virtual(profile: Profile, settings: dict[str, Any] | None = None) -> VirtualDisplay:
    return VirtualDisplay(profile, settings or {})


@hookimpl
def thintact_displays() -> list[Component]:
    return [
        Component("pygame", _pygame, "full-screen pygame/SDL window on an LCD (calibration wizard)"),
        Component("virtual", _virtual, "feeds scenes to the virtual sensor's scene slot"),
    ]
