"""The robot API (Sensor) on a test camera and decoder registered in a private registry.

The test camera renders a tactile scene at 2× the scene grid (each scene pixel a 2×2
block, times a gain, plus the black level, as a Bayer mosaic); the test decoder averages
the blocks back. That exercises the Sensor's plumbing (camera → capture → decoder →
interpreter, threads, frame accounting) exactly, independent of the lensless optics.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from tac_fakes import LIGHTS, SLOTS, block_profile, make_registry

from thintact_sdk.device.sensor import Sensor
from thintact_sdk.errors import CalibrationError, DeviceError
from thintact_sdk.frames import TactileFrame
from thintact_sdk.tactile import Sphere, TactileSimulator, save_device_lut, scene_level_lut


@pytest.fixture(scope="module")
def registry():
    return make_registry()


@pytest.fixture(scope="module")
def profile():
    return block_profile()


@pytest.fixture(scope="module")
def lut(profile):
    return scene_level_lut(profile)


@pytest.fixture(autouse=True)
def _clean_slots(tmp_path, monkeypatch):
    SLOTS.clear()
    monkeypatch.setenv("THINTACT_CALIBRATION_PATH", str(tmp_path / "calibrations"))
    yield
    SLOTS.clear()


def test_read_gives_depth_and_contact(profile, registry, lut):
    press = TactileSimulator.for_profile(profile).press(Sphere(2.0), 0.75, (1.0, 0.5))
    with Sensor(profile, registry=registry, lut=lut, reference_frames=3) as s:
        first = [s.read() for _ in range(s.reference_frames)]  # the reference frames
        assert isinstance(first[0], TactileFrame) and not any(f.contact for f in first)
        assert s.interpreter._ref_count == s.reference_frames == 3
        SLOTS["tac-block"] = press.scene
        frame = s.read()
        assert frame.frame_id == first[-1].frame_id + 1
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


def test_leds_are_set_from_the_profile_and_released(profile, registry, lut):
    from thintact_sdk.formats.profiles import LightConfig

    lit = profile.model_copy(update={"light": LightConfig(
        plugin="tac-test-lights", port="loop://", intensities=[0.5] * 10)}, deep=True)
    LIGHTS.clear()
    with Sensor(lit, registry=registry, lut=lut) as s:
        assert s.light is LIGHTS[0] and LIGHTS[0].opened and LIGHTS[0].port == "loop://"
        assert LIGHTS[0].get_intensities() == [0.5] * 10
    assert not LIGHTS[0].opened


def test_same_api_on_a_replayed_recording(tmp_path, profile, lut):
    """The replay camera plugin plays a recording; the sensor cannot tell the difference."""
    thintact_replay = pytest.importorskip("thintact_replay")
    from tac_fakes import GAIN_DN

    from thintact_sdk.errors import EndOfStreamError
    from thintact_sdk.formats.profiles import CameraConfig
    from thintact_sdk.formats.recording import RecordingWriter

    sim = TactileSimulator.for_profile(profile)
    rec = RecordingWriter(tmp_path / "presses", profile)
    scenes = [sim.flat().scene] + [sim.press(Sphere(2.0), d, (0.0, 0.0)).scene for d in (0.3, 0.8)]
    for i, sc in enumerate(scenes):
        up = np.kron(sc, np.ones((2, 2, 1), np.float32))
        rec.add(np.round(64.0 + GAIN_DN * up).astype(np.uint16), label=f"f{i}",
                timestamp_ns=i * 33_000_000, frame_id=i + 1)
    reg = make_registry()
    reg.register(thintact_replay, "replay")
    replay = profile.model_copy(update={"camera": CameraConfig(
        plugin="replay", settings={"path": str(tmp_path / "presses"), "rate": "fast"})}, deep=True)
    with Sensor(replay, registry=reg, lut=lut) as s:
        frames = [s.read() for _ in range(3)]
        with pytest.raises(EndOfStreamError):
            s.read()
    assert [f.contact for f in frames] == [False, True, True]
    assert frames[2].depth_mm.max() > frames[1].depth_mm.max()
    with Sensor(replay, registry=reg, lut=lut) as s, pytest.raises(EndOfStreamError):
        for _ in s.stream(timeout_s=5.0):
            pass


def test_lut_and_decoder_can_be_swapped(profile, registry, lut):
    from tac_fakes import BlockDecoder

    with Sensor(profile, registry=registry, lut=lut) as s:
        s.read()
        other = scene_level_lut(profile, presses=4, seed=1)
        s.lut = other
        assert s.interpreter.lut is other
        s.decoder = BlockDecoder()
        assert s.read().image.shape == (100, 128, 3)
