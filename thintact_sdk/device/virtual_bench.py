"""The virtual optical bench: scene slots (what the virtual display shows) and the DN scale.

It lives in the core because two plugins meet here: the virtual display (``thintact_displays``)
puts scenes into a slot and the virtual camera (``thintact_virtual``) renders them; neither
imports the other.

A :class:`SceneSlot` holds the scene currently in front of a virtual sensor; the virtual
display sets it, the virtual camera renders it. Slots are process-wide, keyed by a string
(the camera uses ``settings.get("slot", profile.name)``).
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from thintact_sdk.formats.profiles import Profile
from thintact_sdk.simulation.noise import default_white_level_dn


class SceneSlot:
    """A thread-safe holder of one scene (``N × M × 3`` float32 display values) or None."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._scene: np.ndarray | None = None
        self._version = 0

    def set(self, scene: np.ndarray | None) -> None:
        """Show ``scene`` (copied, as float32) or clear the slot with ``None``."""
        value = None if scene is None else np.array(scene, dtype=np.float32, copy=True)
        with self._lock:
            self._scene = value
            self._version += 1

    def get(self) -> np.ndarray | None:
        """The scene currently shown, or None."""
        with self._lock:
            return self._scene

    def snapshot(self) -> tuple[int, np.ndarray | None]:
        """``(version, scene)``: the version changes on every :meth:`set`."""
        with self._lock:
            return self._version, self._scene


_SLOTS: dict[str, SceneSlot] = {}
_SLOTS_LOCK = threading.Lock()


def get_scene_slot(key: str) -> SceneSlot:
    """The process-wide slot named ``key`` (created empty on first use)."""
    with _SLOTS_LOCK:
        if key not in _SLOTS:
            _SLOTS[key] = SceneSlot()
        return _SLOTS[key]


REFERENCE_EXPOSURE_US = 10_000.0
"""Exposure at which ``white_level_dn`` is defined; the signal scales linearly with exposure."""


def white_level_dn(profile: Profile, settings: dict[str, Any]) -> float:
    """DN above black of the brightest all-white pixel at the reference exposure."""
    v = settings.get("white_level_dn")
    return default_white_level_dn(profile.noise) if v is None else float(v)


def signal_scale_dn(profile: Profile, settings: dict[str, Any] | None = None) -> float:
    """DN (above black) per simulator unit used by the virtual camera at the reference
    exposure (multiply by ``exposure_us / 10000`` at other exposures)."""
    from thintact_sdk.simulation.simulator import Simulator

    return Simulator(profile).reference_gain(white_level_dn(profile, settings or {}))
