"""What this machine can see: ``/dev/video*`` nodes, serial ports and USB devices.

The library behind ``thintact devices``: :func:`list_devices` returns every section as plain
data (the command's ``--json``); the command only parses, builds the plugins' device listers
and prints. Each function answers an empty list (or an ``error`` string for USB) on a machine
without that kind of device; none raises for a missing bus.
"""

from __future__ import annotations

import glob
import importlib
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from thintact_sdk.errors import ThinTactError

__all__ = ["UVC_SECTION", "list_devices", "load_usb_backend", "serial_ports", "usb_devices", "uvc_devices"]

UVC_SECTION = "uvc"
"""The key of :func:`uvc_devices`'s section in :func:`list_devices` (``--json``)."""


def uvc_devices() -> list[dict[str, str]]:
    """``/dev/video*`` nodes, sorted by path: ``path``, ``by_id`` (its ``/dev/v4l/by-id`` link,
    ``""`` without one) and ``name`` (the V4L2 card name from sysfs, ``""`` when unreadable)."""
    by_id = {os.path.realpath(link): link for link in sorted(glob.glob("/dev/v4l/by-id/*"))}
    out = []
    for node in sorted(glob.glob("/dev/video*")):
        try:
            card = (Path("/sys/class/video4linux") / Path(node).name / "name").read_text(
                encoding="utf-8").strip()
        except OSError:
            card = ""
        out.append({"path": node, "by_id": by_id.get(os.path.realpath(node), ""), "name": card})
    return out


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
    lister's data under its name (``lister_data``, in its order), then ``uvc``
    (:func:`uvc_devices`), ``serial`` (:func:`serial_ports`) and ``usb``
    (:func:`usb_devices` through ``usb_backend``)."""
    return dict(lister_data or {}) | {
        UVC_SECTION: uvc_devices(),
        "serial": serial_ports(),
        "usb": usb_devices(usb_backend),
    }
