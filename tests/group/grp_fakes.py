"""Scripted cameras for the sensor-group tests: paced, stallable, unpluggable, triggerable,
with optional synthetic timestamps, in a private plugin registry."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

import thintact_sdk
from thintact_sdk.device.registry import PluginRegistry
from thintact_sdk.device.sensor import Sensor
from thintact_sdk.errors import DeviceLostError, DeviceTimeoutError, EndOfStreamError
from thintact_sdk.formats.profiles import CameraConfig, Profile, load_profile
from thintact_sdk.frames import RawFrame
from thintact_sdk.interfaces import Camera, CameraCapabilities


class ScriptedCamera(Camera):
    """Settings: ``fps`` (pace), ``offset_ms`` / ``synthetic`` (timestamps k·period + offset
    instead of the clock), ``stall`` (a threading.Event: while set, reads time out),
    ``lose_after`` / ``end_after`` (frames before DeviceLostError / EndOfStreamError)."""

    name = "grp-test-cam"

    def __init__(self, profile: Profile, settings: dict[str, Any]) -> None:
        self.profile = profile
        self.fps = float(settings.get("fps", 100.0))
        self.offset_ns = int(float(settings.get("offset_ms", 0.0)) * 1e6)
        self.synthetic = bool(settings.get("synthetic", False))
        self.stall: threading.Event = settings.get("stall") or threading.Event()
        self.lose_after = settings.get("lose_after")
        self.end_after = settings.get("end_after")
        self._id = 0
        self._next = 0.0

    def open(self) -> None:
        self._is_open = True
        self._next = time.monotonic()

    def close(self) -> None:
        self._is_open = False

    def capabilities(self) -> CameraCapabilities:
        return CameraCapabilities(16, 16, ["Mono8"], "Mono8", self.fps)

    def _wait_frame(self, timeout_s: float) -> None:
        if self.stall.is_set():
            time.sleep(timeout_s)
            raise DeviceTimeoutError("scripted stall")
        self._next += 1.0 / self.fps
        time.sleep(max(0.0, self._next - time.monotonic()))

    def read(self, timeout_s: float = 2.0) -> RawFrame:
        if self.lose_after is not None and self._id >= self.lose_after:
            raise DeviceLostError("scripted unplug")
        if self.end_after is not None and self._id >= self.end_after:
            raise EndOfStreamError("scripted end")
        self._wait_frame(timeout_s)
        self._id += 1
        stamp = (self._id * int(1e9 / self.fps) if self.synthetic else time.monotonic_ns())
        return RawFrame(np.full((16, 16), self._id, np.uint8), stamp + self.offset_ns,
                        self._id, "Mono8")


class TriggeredCamera(ScriptedCamera):
    """A frame per ``fire_trigger()`` once ``set_trigger("Software")`` was called."""

    name = "grp-trigger-cam"

    def __init__(self, profile: Profile, settings: dict[str, Any]) -> None:
        super().__init__(profile, settings)
        self.source: str | None = None
        self.fired = threading.Semaphore(0)
        self.triggers = 0

    def set_trigger(self, source: str | None) -> None:
        self.source = source

    def fire_trigger(self) -> None:
        self.triggers += 1
        self.fired.release()

    def _wait_frame(self, timeout_s: float) -> None:
        if self.source is None:
            super()._wait_frame(timeout_s)
        elif not self.fired.acquire(timeout=timeout_s):
            raise DeviceTimeoutError("no trigger")


class _Plugin:
    @thintact_sdk.hookimpl
    def thintact_cameras(self):
        return [thintact_sdk.Component("grp-test-cam", ScriptedCamera, "scripted"),
                thintact_sdk.Component("grp-trigger-cam", TriggeredCamera, "triggered")]


REGISTRY = PluginRegistry()
REGISTRY.register(_Plugin(), "grp-test")


def scripted_sensor(plugin: str = "grp-test-cam", **settings: Any) -> Sensor:
    """A sensor on the scripted camera (raw frames only: open the group with process=False)."""
    base = load_profile("virtual-mini")
    prof = base.model_copy(update={"name": "scripted",
                                   "camera": CameraConfig(plugin=plugin, settings={})})
    return Sensor(prof, registry=REGISTRY, camera_settings=settings, read_timeout_s=0.1)
