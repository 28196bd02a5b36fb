"""The virtual display: scenes go to the virtual sensor's scene slot.

The virtual camera (plugin ``thintact-virtual``) renders whatever scene its slot holds
(slot key ``camera.settings.slot``, default the profile name), so the calibration wizard
runs end to end with no hardware. ``close()`` empties the slot, handing the camera back to
its own scene library.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_displays.layout import check_scene_shape
from thintact_sdk.errors import PluginError
from thintact_sdk.interfaces import Display
from thintact_sdk.plugin_support import Profile


def slot_key(profile: Profile, settings: dict[str, Any]) -> str:
    """The scene-slot key shared with the virtual camera.

    ``settings["slot"]`` wins, then the camera's ``settings.slot``, then the profile name.
    """
    if settings.get("slot"):
        return str(settings["slot"])
    if profile.camera is not None and profile.camera.settings.get("slot"):
        return str(profile.camera.settings["slot"])
    return profile.name


class VirtualDisplay(Display):
    """Shows scenes to the virtual camera of ``profile``.

    Parameters
    ----------
    profile
        Device profile (scene size, slot key).
    settings
        ``slot``: override of the scene-slot key.
    """

    name = "virtual"

    def __init__(self, profile: Profile, settings: dict[str, Any]) -> None:
        self.profile = profile
        self.key = slot_key(profile, settings)
        self._slot: Any = None

    def open(self) -> None:
        try:
            from thintact_sdk.plugin_support import get_scene_slot
        except ImportError as err:
            raise PluginError(
                "the virtual display needs the virtual sensor plugin (thintact-virtual); "
                f"install plugins/thintact_virtual ({err})"
            ) from None
        self._slot = get_scene_slot(self.key)

    def close(self) -> None:
        if self._slot is not None:
            self._slot.set(None)
            self._slot = None

    def show(self, scene: np.ndarray) -> None:
        """Put ``scene`` (``N × M × 3`` in [0, 1]) in the slot; the next frames render it."""
        if self._slot is None:
            self.open()
        check_scene_shape(scene, self.profile)
        self._slot.set(np.array(scene, dtype=np.float32, copy=True))
