"""The robot API (Sensor) on a test camera and decoder registered in a private registry.

The test camera renders a tactile scene at 2× the scene grid (each scene pixel a 2×2
block, times a gain, plus the black level, as a Bayer mosaic); the test decoder averages
the blocks back. That exercises the Sensor's plumbing (camera → capture → decoder →
interpreter, threads, frame accounting) exactly, independent of the lensless optics.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest

import thintact_sdk
from thintact_sdk.bayer import mosaic_from_rgb
from thintact_sdk.errors import CalibrationError, DeviceError
from thintact_sdk.frames import RawFrame, TactileFrame
from thintact_sdk.interfaces import Camera, CameraCapabilities, Decoder
from thintact_sdk.plugin_manager import PluginRegistry
from thintact_sdk.profile import CameraConfig, DecoderConfig, SensorSpec, load_profile
from thintact_sdk.sensor import Sensor
from thintact_sdk.tactile import Sphere, TactileSimulator, save_device_lut, scene_level_lut

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


class _TestPlugin:
    @thintact_sdk.hookimpl
    def thintact_cameras(self):
        return [thintact_sdk.Component("tac-test-cam", BlockCamera, "test camera")]

    @thintact_sdk.hookimpl
    def thintact_decoders(self):
        return [thintact_sdk.Component("tac-test-decoder", lambda p, s: BlockDecoder(), "test")]


@pytest.fixture(scope="module")
def registry() -> PluginRegistry:
    reg = PluginRegistry()
    reg.register(_TestPlugin(), "tac-test")
    return reg


@pytest.fixture(scope="module")
def profile():
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


@pytest.fixture(scope="module")
def lut(profile):
    return scene_level_lut(profile)


@pytest.fixture(autouse=True)
def _clean_slots(tmp_path, monkeypatch):
    SLOTS.clear()
    monkeypatch.setenv("THINTACT_CALIBRATIONS", str(tmp_path / "calibrations"))
    yield
    SLOTS.clear()


def test_read_gives_depth_and_contact(profile, registry, lut):
    press = TactileSimulator.for_profile(profile).press(Sphere(2.0), 0.75, (1.0, 0.5))
    with Sensor(profile, registry=registry, lut=lut) as s:
        first = s.read()
        assert isinstance(first, TactileFrame) and not first.contact
        SLOTS["tac-block"] = press.scene
        frame = s.read()
        assert frame.frame_id == first.frame_id + 1
        assert frame.contact and frame.latency_ms is not None
        m = press.depth_mm > 0.1
        assert float(np.sqrt(np.mean((frame.depth_mm - press.depth_mm)[m] ** 2))) < 0.06
        assert s.read_measurement().data.shape == (200, 256, 3)
        assert s.read_image().shape == (100, 128, 3)
        cam = s.camera
    assert cam is not None and not cam.is_open


def test_stored_lut_is_used_and_missing_lut_is_explained(profile, registry, lut):
    with Sensor(profile, registry=registry) as s, pytest.raises(CalibrationError, match="calibrate-tactile"):
        s.read()
    path = save_device_lut(lut, profile)
    assert path.parts[-3:] == ("tac-block", "tactile", "lut.npz")
    with Sensor(profile, registry=registry) as s:
        assert s.read().meta.get("depth") is None
        assert s.lut.meta["profile"] == "tac-block"


def test_stream_returns_the_newest_frame_to_a_slow_consumer(profile, registry, lut):
    SLOTS["tac-block"] = TactileSimulator.for_profile(profile).flat().scene
    s = Sensor(profile, registry=registry, lut=lut, camera_settings={"fps": 100.0}).open()
    ids = []
    try:
        for frame in s.stream(max_frames=4):
            ids.append(frame.frame_id)
            time.sleep(0.15)  # a slow robot loop
    finally:
        s.close()
    assert ids == sorted(ids) and len(set(ids)) == 4
    assert max(np.diff(ids)) > 3  # frames in between were skipped, not queued
    assert s.stats.delivered == 4
    assert s.stats.skipped + s.stats.consumer_dropped > 0
    assert s.stats.captured >= ids[-1] - ids[0]


def test_two_fingers_at_once(profile, registry, lut):
    press = TactileSimulator.for_profile(profile).press(Sphere(2.0), 0.8, (0.0, 0.0))
    left = Sensor(profile, registry=registry, lut=lut, camera_settings={"slot": "left"})
    right = Sensor(profile, registry=registry, lut=lut, camera_settings={"slot": "right"})
    with left, right:
        left.read(), right.read()
        SLOTS["left"] = press.scene
        a, b = next(left.stream(max_frames=1)), next(right.stream(max_frames=1))
    assert a.contact and not b.contact


def test_reading_a_closed_sensor_is_a_clear_error(profile, registry, lut):
    s = Sensor(profile, registry=registry, lut=lut)
    with pytest.raises(DeviceError, match="not open"):
        s.read()
