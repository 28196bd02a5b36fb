"""Two GenICam cameras of one producer as a sensor group (viky.cti), and the trigger
features against a producer that has them (a scripted node map) and one that has not."""

from __future__ import annotations

from typing import Any

import pytest
from thintact_genicam.producers import viky_producer
from thintact_genicam.trigger import fire_software_trigger, set_trigger

import thintact_sdk as thintact
from thintact_sdk.device.sensor import Sensor
from thintact_sdk.errors import UnsupportedFeatureError
from thintact_sdk.formats.profiles import CameraConfig, load_profile

VIKY = viky_producer()
MONO = {"Width": 320, "Height": 256, "PixelFormat": "Mono8", "AcquisitionFrameRate": 100.0}


def _viky_sensor(serial: str) -> Sensor:
    base = load_profile("virtual-mini")
    cam = CameraConfig(plugin="genicam", settings={"cti": str(VIKY), "serial": serial, **MONO})
    noise = base.noise.model_copy(update={"black_level_dn": 4.0, "saturation_dn": 255.0})
    return Sensor(base.model_copy(update={"name": f"viky-{serial}", "camera": cam,
                                          "noise": noise}))


@pytest.mark.skipif(VIKY is None, reason="genicam wheel without viky.cti")
def test_two_cameras_of_one_producer_stream_as_a_group():
    with thintact.open_group([_viky_sensor("0"), _viky_sensor("1")], process=False,
                             max_skew_ms=10.0) as g:
        pairs = list(g.stream(max_frames=40))
        summary = g.skew_summary()
        status = g.status()
    assert all(p.complete for p in pairs)
    assert summary["pairs"] == 40 and summary["max_ms"] <= 10.0
    assert {p.frames["viky-0"].data.shape for p in pairs} == {(256, 320)}
    assert all(s.delivered == 40 for s in status.values())


@pytest.mark.skipif(VIKY is None, reason="genicam wheel without viky.cti")
def test_trigger_on_a_producer_without_trigger_features_is_reported():
    with pytest.raises(UnsupportedFeatureError, match="member 'viky-0'.*no TriggerMode"):
        thintact.open_group([_viky_sensor("0"), _viky_sensor("1")], process=False,
                            trigger="software")
    # the failed open released both cameras: the producer opens again
    with thintact.open_group([_viky_sensor("0")], process=False) as g:
        assert g.read().complete


class _Node:
    def __init__(self, value: Any = None, symbolics: tuple[str, ...] | None = None) -> None:
        self.value = value
        if symbolics is not None:
            self.symbolics = symbolics
        self.executed = 0
        self.node = self

    def get_access_mode(self) -> int:
        return 4  # RW

    def execute(self) -> None:
        self.executed += 1


class _TriggerNodeMap:
    """The SFNC trigger features of a typical industrial camera."""

    def __init__(self) -> None:
        self.TriggerSelector = _Node("AcquisitionStart", ("AcquisitionStart", "FrameStart"))
        self.TriggerMode = _Node("Off", ("Off", "On"))
        self.TriggerSource = _Node("Line0", ("Line0", "Line1", "Software"))
        self.TriggerSoftware = _Node()

    def has_node(self, name: str) -> bool:
        return hasattr(self, name)


def test_trigger_features_are_written_in_sfnc_order():
    nm = _TriggerNodeMap()
    set_trigger(nm, "Software")
    assert (nm.TriggerSelector.value, nm.TriggerSource.value, nm.TriggerMode.value) == (
        "FrameStart", "Software", "On")
    fire_software_trigger(nm)
    fire_software_trigger(nm)
    assert nm.TriggerSoftware.executed == 2
    set_trigger(nm, "Line1")
    assert (nm.TriggerSource.value, nm.TriggerMode.value) == ("Line1", "On")
    set_trigger(nm, None)
    assert nm.TriggerMode.value == "Off"
    with pytest.raises(UnsupportedFeatureError, match="'Line7' is not offered.*Line0, Line1"):
        set_trigger(nm, "Line7")
    del nm.TriggerSoftware
    with pytest.raises(UnsupportedFeatureError, match="no TriggerSoftware"):
        fire_software_trigger(nm)


@pytest.mark.skipif(VIKY is None, reason="genicam wheel without viky.cti")
def test_a_refused_trigger_leaves_the_camera_streaming():
    with _viky_sensor("2") as sensor:
        cam = sensor.camera
        with pytest.raises(UnsupportedFeatureError, match="no TriggerMode"):
            cam.set_trigger("Software")
        with pytest.raises(UnsupportedFeatureError, match="no TriggerSoftware"):
            cam.fire_trigger()
        assert sensor.read_raw().data.shape == (256, 320)  # acquisition was restarted
