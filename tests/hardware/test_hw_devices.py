"""thintact devices: GenICam producers (viky.cti), serial ports, USB through a pyusb backend."""

from __future__ import annotations

import array
import json
import types

import pytest
import usb.backend
import yaml
from thintact_genicam.producers import viky_producer

from thintact_sdk import Component, hookimpl
from thintact_sdk.apps.cli.main import main
from thintact_sdk.device.host_devices import usb_devices
from thintact_sdk.formats.profiles import load_profile

STRINGS = {1: "ACME Vision", 2: "USB3 camera", 3: "U500123"}


class FakeBus(usb.backend.IBackend):
    """A USB bus with two devices, answering pyusb's standard requests (descriptors, strings)."""

    def __init__(self):
        self.opened = []
        self.devices = [
            types.SimpleNamespace(
                bLength=18, bDescriptorType=1, bcdUSB=0x0300, bDeviceClass=0xEF,
                bDeviceSubClass=2, bDeviceProtocol=1, bMaxPacketSize0=9, idVendor=0x1234,
                idProduct=0x0003, bcdDevice=0x0100, iManufacturer=1, iProduct=2,
                iSerialNumber=3, bNumConfigurations=1, address=4, bus=2, port_number=1,
                port_numbers=(1,), speed=4),
            types.SimpleNamespace(
                bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=2,
                bDeviceSubClass=0, bDeviceProtocol=0, bMaxPacketSize0=64, idVendor=0x2E8A,
                idProduct=0x000A, bcdDevice=0x0100, iManufacturer=0, iProduct=0,
                iSerialNumber=0, bNumConfigurations=1, address=7, bus=1, port_number=3,
                port_numbers=(3,), speed=3),
        ]

    def enumerate_devices(self):
        return iter(range(len(self.devices)))

    def get_device_descriptor(self, dev):
        return self.devices[dev]

    def open_device(self, dev):
        self.opened.append(dev)
        return dev

    def close_device(self, dev_handle):
        return None

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        assert bmRequestType == 0x80 and bRequest == 0x06  # standard GET_DESCRIPTOR, IN
        desc_type, index = wValue >> 8, wValue & 0xFF
        assert desc_type == 3  # string descriptor
        if index == 0:
            payload = bytes([4, 3, 0x09, 0x04])  # LANGID en-US
        else:
            assert wIndex == 0x0409
            text = STRINGS[index].encode("utf-16-le")
            payload = bytes([2 + len(text), 3]) + text
        n = min(len(payload), len(data))
        data[:n] = array.array("B", payload[:n])
        return n


def make_bus():
    return FakeBus()


def test_usb_devices_through_an_injected_backend():
    bus = FakeBus()
    found = usb_devices(bus)
    assert found["error"] is None
    first, second = found["devices"]
    assert first["vid_pid"] == "1234:0003" and (first["bus"], first["address"]) == (2, 4)
    assert (first["manufacturer"], first["product"], first["serial"]) == (
        "ACME Vision", "USB3 camera", "U500123")
    assert second["vid_pid"] == "2e8a:000a" and second["product"] == ""
    assert bus.opened  # strings really went through the backend's control transfers


def test_devices_cli_text_and_json(tmp_path, capsys, monkeypatch):
    viky = viky_producer()
    if viky is None:
        pytest.skip("genicam wheel without viky.cti")
    # a user profile naming the producer, and a missing producer on the GenTL path
    d = load_profile("virtual-mini").contract_dict()
    d["name"] = "my-viky"
    d["camera"] = {"plugin": "genicam", "settings": {"cti": str(viky)}}
    (tmp_path / "profiles").mkdir()
    (tmp_path / "profiles" / "my-viky.yaml").write_text(yaml.safe_dump(d))
    monkeypatch.setenv("THINTACT_PROFILE_PATH", str(tmp_path / "profiles"))
    monkeypatch.setenv("GENICAM_GENTL64_PATH", str(tmp_path / "vendor.cti"))
    assert main(["devices", "--usb-backend", "test_hw_devices:make_bus"]) == 0
    out = capsys.readouterr().out
    assert "(profile my-viky)" in out and "serial 2  id VikyTL_DEV_blue" in out
    assert "vendor.cti  (GENICAM_GENTL64_PATH)" in out and "producer file not found" in out
    assert "1234:0003  ACME Vision USB3 camera  serial U500123" in out
    assert main(["devices", "--json", "--no-profiles", "--cti", str(viky),
                 "--usb-backend", "test_hw_devices:make_bus"]) == 0
    found = json.loads(capsys.readouterr().out)
    assert set(found) == {"genicam", "uvc", "serial", "usb"}
    viky_entries = [e for e in found["genicam"] if e["producer"] == str(viky.resolve())]
    assert viky_entries and len(viky_entries[0]["devices"]) == 3
    assert [d["vid_pid"] for d in found["usb"]["devices"]] == ["1234:0003", "2e8a:000a"]
    assert isinstance(found["serial"], list)


def test_bad_usb_backend_is_a_one_line_error(capsys):
    assert main(["devices", "--no-profiles", "--usb-backend", "nosuchmodule:x"]) == 2
    assert "cannot load USB backend" in capsys.readouterr().err


def test_a_hanging_producer_is_reported_not_waited_for():
    import time

    from thintact_genicam.listing import bounded

    t0 = time.monotonic()
    devices, error = bounded(lambda cti: time.sleep(2.0) or [], "slow.cti", 0.2)
    assert devices == [] and "did not finish enumerating within" in error
    assert time.monotonic() - t0 < 1.0


def _lister_plugin() -> types.ModuleType:
    """A plugin with a device lister adding ``--fake-source`` and one whose factory raises."""
    mod = types.ModuleType("fake_lister_plugin")

    def build(parser):
        parser.add_argument("--fake-source", default="none")
        return lambda args: ({"source": args.fake_source, "timeout": args.timeout},
                             ["Fake sources", f"  {args.fake_source} within {args.timeout:g} s"])

    @hookimpl
    def thintact_device_listers():
        return [Component("fake", build), Component("broken", lambda parser: 1 / 0)]

    mod.thintact_device_listers = thintact_device_listers
    return mod


def test_devices_only_calls_the_listers(monkeypatch, capsys):
    """The core command knows no source: each lister adds its options and returns its section
    (data under its name, text lines); a lister that fails to build is one line of its own."""
    import thintact_sdk.device.registry as registry

    monkeypatch.setattr(registry, "_REGISTRY", None)  # this test's registry, restored after
    registry.get_registry().register(_lister_plugin(), "fake-listers")
    assert main(["devices", "--json", "--no-profiles", "--fake-source", "bench", "--timeout", "3",
                 "--usb-backend", "test_hw_devices:make_bus"]) == 0
    found = json.loads(capsys.readouterr().out)
    assert found["fake"] == {"source": "bench", "timeout": 3.0}
    assert "failed to build" in found["broken"]["error"]
    assert main(["devices", "--no-profiles", "--usb-backend", "test_hw_devices:make_bus"]) == 0
    out = capsys.readouterr().out
    assert "Fake sources\n  none within 10 s\n" in out and "device lister 'broken'" in out


def test_the_library_listing_is_the_commands(capsys):
    """``thintact devices --json`` prints exactly what ``device.host_devices.list_devices``
    returns (no lister's section: ``--no-profiles`` and a registry without listers)."""
    from thintact_sdk.device.host_devices import list_devices
    from thintact_sdk.device.registry import get_registry

    assert main(["devices", "--json", "--no-profiles", "--usb-backend", "test_hw_devices:make_bus"]) == 0
    printed = json.loads(capsys.readouterr().out)
    listers = {k: v for k, v in printed.items() if k in get_registry().components("device_lister")}
    expected = json.loads(json.dumps(list_devices(listers, make_bus()), default=str))
    assert printed == expected
    assert [d["vid_pid"] for d in printed["usb"]["devices"]] == ["1234:0003", "2e8a:000a"]
