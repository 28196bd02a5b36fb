"""What this machine can see: serial ports and USB devices (cameras come from the plugins'
device listers, e.g. the uvc plugin's ``/dev/video*`` section).

The library behind ``thintact devices``: :func:`list_devices` returns every section as plain
data (the command's ``--json``); the command only parses, builds the plugins' device listers
and prints. Each function answers an empty list (or an ``error`` string for USB) on a machine
without that kind of device; none raises for a missing bus.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

from thintact_sdk.errors import ThinTactError

__all__ = ["list_devices", "load_usb_backend", "serial_ports", "usb_devices"]

def serial_ports() -> list[dict[str, Any]]:
    """Serial ports (``serial.tools.list_ports``), sorted by device: ``device``,
    ``description``, ``vid_pid`` (``"vvvv:pppp"`` hex, ``""`` when not USB), ``serial``, ``hwid``."""
    from serial.tools import list_ports

    out = []
    for port in sorted(list_ports.comports(), key=lambda p: p.device):
        vid_pid = f"{port.vid:04x}:{port.pid:04x}" if port.vid is not None and port.pid is not None else ""
        out.append({"device": port.device, "description": port.description or "",
                    "vid_pid": vid_pid, "serial": port.serial_number or "", "hwid": port.hwid or ""})
    return out


def load_usb_backend(spec: str) -> Any:
    """The pyusb backend ``MODULE:ATTR`` names: the attribute, called when it is callable.

    Raises
    ------
    ThinTactError
        ``spec`` is not ``MODULE:ATTR``, or the module or attribute cannot be loaded
        (named as ``--usb-backend``).
    """
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise ThinTactError(f"--usb-backend needs MODULE:ATTR, got {spec!r}")
    try:
        obj = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as err:
        raise ThinTactError(f"cannot load USB backend {spec}: {err}") from None
    return obj() if callable(obj) else obj


def usb_devices(backend: Any = None) -> dict[str, Any]:
    """USB devices as ``{"devices": [...], "error": str | None}``.

    Each device: ``bus``, ``address``, ``vid_pid`` (``"vvvv:pppp"`` hex), ``class``,
    ``manufacturer``, ``product``, ``serial`` (``""`` where the device has no such string or
    may not be opened). ``error`` names why nothing could be enumerated (no backend, a USB error).

    Parameters
    ----------
    backend
        A ``usb.backend.IBackend``; None lets pyusb pick libusb1/libusb0/openusb.
    """
    import usb.core
    import usb.util

    try:
        found = list(usb.core.find(find_all=True, backend=backend) or [])
    except usb.core.NoBackendError:
        return {"devices": [], "error": "no USB backend available (install libusb-1.0)"}
    except (usb.core.USBError, OSError) as err:
        return {"devices": [], "error": f"USB enumeration failed: {err}"}
    devices = []
    for dev in found:
        entry: dict[str, Any] = {
            "bus": dev.bus, "address": dev.address,
            "vid_pid": f"{dev.idVendor:04x}:{dev.idProduct:04x}",
            "class": dev.bDeviceClass,
        }
        for key, index in (("manufacturer", dev.iManufacturer), ("product", dev.iProduct),
                           ("serial", dev.iSerialNumber)):
            entry[key] = ""
            if index:
                try:
                    entry[key] = usb.util.get_string(dev, index) or ""
                except (usb.core.USBError, ValueError, NotImplementedError, OSError):
                    entry[key] = ""  # no permission to open the device, or no string support
        usb.util.dispose_resources(dev)
        devices.append(entry)
    return {"devices": devices, "error": None}


def list_devices(lister_data: Mapping[str, Any] | None = None, usb_backend: Any = None) -> dict[str, Any]:
    """Every section as plain data (what ``thintact devices --json`` prints): each device
    lister's data under its name (``lister_data``, in its order), then ``serial``
    (:func:`serial_ports`) and ``usb``
    (:func:`usb_devices` through ``usb_backend``)."""
    return dict(lister_data or {}) | {
        "serial": serial_ports(),
        "usb": usb_devices(usb_backend),
    }
