"""Test doubles for the Sensor: a camera that shows tactile scenes as 2×2 pixel blocks and
the decoder that averages the blocks back (exact), in a private plugin registry."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

import thintact_sdk
from thintact_sdk.device.registry import PluginRegistry
from thintact_sdk.errors import DeviceError
from thintact_sdk.formats.profiles import (
    CameraConfig,
    DecoderConfig,
    Profile,
    SensorSpec,
    load_profile,
)
from thintact_sdk.frames import RawFrame
from thintact_sdk.interfaces import Camera, CameraCapabilities, Decoder, LightController
from thintact_sdk.pixels.bayer import mosaic_from_rgb
from thintact_sdk.tactile import TactileSimulator

GAIN_DN = 2000.0
SLOTS: dict[str, np.ndarray] = {}


class BlockCamera(Camera):
    name = "tac-test-cam"

    def __init__(self, profile, settings: dict[str, Any]) -> None:
        self.profile = profile
        self.slot = settings.get("slot", profile.name)
        self.fps = float(settings.get("fps", 0.0))
        self.flat = TactileSimulator.for_profile(profile).flat().scene
        self._id = 0
        self._last = 0.0

    def open(self) -> None:
        self._is_open = True

    def close(self) -> None:
        self._is_open = False

    def capabilities(self) -> CameraCapabilities:
        s = self.profile.sensor
        return CameraCapabilities(2 * s.cols, 2 * s.rows, ["BayerRG12"], "BayerRG12", self.fps)

    def read(self, timeout_s: float = 2.0) -> RawFrame:
        if not self.is_open:
            raise DeviceError("closed")
        if self.fps > 0:
            wait = self._last + 1.0 / self.fps - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            self._last = time.monotonic()
        scene = SLOTS.get(self.slot, self.flat)
        up = np.kron(scene, np.ones((2, 2, 1), np.float32))
        dn = np.round(64.0 + GAIN_DN * up).astype(np.uint16)
        self._id += 1
        return RawFrame(mosaic_from_rgb(dn), time.monotonic_ns(), self._id, "BayerRG12", 10000.0)


class BlockDecoder(Decoder):
    name = "tac-test-decoder"

    def decode(self, signal: np.ndarray) -> np.ndarray:
        r, s, c = signal.shape
        return (signal.reshape(r // 2, 2, s // 2, 2, c).mean(axis=(1, 3)) / GAIN_DN).astype(
            np.float32
        )


class RecordingLights(LightController):
    """Remembers what it was told; ``LIGHTS`` holds every instance."""

    def __init__(self, port, settings) -> None:
        self.port = port
        self.levels = [0.0] * 10
        self.opened = False
        LIGHTS.append(self)

    def open(self) -> None:
        self.opened = True

    def close(self) -> None:
        self.opened = False

    @property
    def led_count(self) -> int:
        return 10

    def set_intensity(self, index: int, level: float) -> None:
        self.levels[index] = level

    def set_all(self, levels: list[float]) -> None:
        self.levels = list(levels)

    def get_intensities(self) -> list[float]:
        return list(self.levels)


LIGHTS: list[RecordingLights] = []


class _TestPlugin:
    @thintact_sdk.hookimpl
    def thintact_cameras(self):
        return [thintact_sdk.Component("tac-test-cam", BlockCamera, "test camera")]

    @thintact_sdk.hookimpl
    def thintact_light_controllers(self):
        return [thintact_sdk.Component("tac-test-lights", RecordingLights, "test lights")]

    @thintact_sdk.hookimpl
    def thintact_decoders(self):
        return [thintact_sdk.Component("tac-test-decoder", lambda p, s: BlockDecoder(), "test")]


def make_registry() -> PluginRegistry:
    """A private registry holding the test camera and decoder."""
    reg = PluginRegistry()
    reg.register(_TestPlugin(), "tac-test")
    return reg


def block_profile() -> Profile:
    """virtual-finger with a 2×-scene sensor, the test camera and the test decoder."""
    base = load_profile("virtual-finger")
    p = base.model_copy(
        update={
            "name": "tac-block",
            "sensor": SensorSpec(rows=2 * base.scene.rows, cols=2 * base.scene.cols,
                                 pixel_pitch_um=base.scene.pixel_pitch_um / 2),
            "camera": CameraConfig(plugin="tac-test-cam", settings={}),
            "decoder": DecoderConfig(plugin="tac-test-decoder"),
        },
        deep=True,
    )
    return p


