"""``thintact devices``: the cameras, serial ports and USB devices this machine can see.

Sections
--------
GenICam
    For each GenTL producer (``camera.settings.cti`` of the shipped and user profiles,
    ``--cti PATH``, and ``GENICAM_GENTL64_PATH``), the devices it offers. Producers are only
    loaded when named; nothing is broadcast on a network by this command itself.
UVC
    ``/dev/video*`` nodes with their ``/dev/v4l/by-id`` names.
Serial
    Serial ports (``serial.tools.list_ports``) with USB VID:PID where known; use one as a
    profile's ``light.port``.
USB
    Every USB device by VID:PID (pyusb). The backend is injectable (``--usb-backend
    MODULE:ATTR`` naming a ``usb.backend.IBackend`` or a callable returning one), which is
    how it is tested on machines without a USB bus.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import importlib
import json
import os
from pathlib import Path
from typing import Any

from thintact_sdk.apps.cli.argtypes import positive_float
from thintact_sdk.device.registry import get_registry
from thintact_sdk.errors import PluginError, ThinTactError
from thintact_sdk.formats.profiles import available_profiles, read_profile_file

GENTL_PATH_ENV = "GENICAM_GENTL64_PATH"
CLI_DESCRIPTION = """\
List what this machine can see:
  GenICam  devices of each GenTL producer named by a profile (camera.settings.cti),
           by --cti, or by GENICAM_GENTL64_PATH
  UVC      /dev/video* nodes with their /dev/v4l/by-id names
  Serial   serial ports with USB VID:PID (use one as a profile's light.port)
  USB      every USB device by VID:PID with its strings (pyusb; --usb-backend injects one)
"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("devices", help="list GenICam and UVC cameras, serial ports and USB devices",
                       description=CLI_DESCRIPTION,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cti", action="append", default=[], metavar="PATH",
                   help="also enumerate this GenTL producer (repeatable)")
    p.add_argument("--no-profiles", action="store_true",
                   help="do not load the producers named by profiles")
    p.add_argument("--usb-backend", metavar="MODULE:ATTR",
                   help="pyusb backend to use (an IBackend, or a callable returning one)")
    p.add_argument("--timeout", type=positive_float, default=10.0, metavar="S",
                   help="longest wait for one GenTL producer's enumeration (default 10)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


# -- collection ------------------------------------------------------------------------
def genicam_producers(extra: list[str], from_profiles: bool = True) -> dict[str, list[str]]:
    """Producer path → what named it (``profile NAME``, ``--cti``, the environment variable)."""
    named: dict[str, list[str]] = {}
    if from_profiles:
        for name, path in sorted(available_profiles().items()):
            try:
                prof = read_profile_file(path)
            except ThinTactError:
                continue
            cam = prof.camera
            if cam is None or cam.plugin != "genicam" or not cam.settings.get("cti"):
                continue
            cti = str(prof.resolve_path(str(cam.settings["cti"])))
            named.setdefault(cti, []).append(f"profile {name}")
    for cti in extra:
        named.setdefault(str(Path(cti).expanduser().resolve()), []).append("--cti")
    for d in os.environ.get(GENTL_PATH_ENV, "").split(os.pathsep):
        if not d:
            continue
        files = sorted(Path(d).glob("*.cti")) if Path(d).is_dir() else [Path(d)]
        for f in files:
            named.setdefault(str(f.resolve()), []).append(GENTL_PATH_ENV)
    return named


def _bounded(fn: Any, arg: str, timeout_s: float) -> tuple[list[dict[str, Any]], str | None]:
    """``fn(arg)`` on a worker thread; a producer that hangs is reported, not waited for."""
    pool = cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="gentl-enum")
    future = pool.submit(fn, arg)
    try:
        return future.result(timeout=timeout_s), None
    except cf.TimeoutError:
        return [], f"the producer did not finish enumerating within {timeout_s:.0f} s"
    except ThinTactError as err:
        return [], str(err)
    finally:
        pool.shutdown(wait=False)


def genicam_devices(extra: list[str], from_profiles: bool = True,
                    timeout_s: float = 10.0) -> list[dict[str, Any]]:
    """One entry per producer: ``producer``, ``named_by``, ``devices`` and ``error``.

    A producer whose enumeration takes longer than ``timeout_s`` is reported as hanging.
    """
    out: list[dict[str, Any]] = []
    for cti, named_by in genicam_producers(extra, from_profiles).items():
        entry: dict[str, Any] = {"producer": cti, "named_by": named_by, "devices": [],
                                 "error": None}
        if not Path(cti).is_file():
            entry["error"] = "producer file not found (install the camera vendor's GenTL SDK)"
        else:
            try:
                lister = get_registry().get("device_lister", "genicam").factory
            except PluginError:
                entry["error"] = "the thintact-genicam plugin (harvesters) is not installed"
            else:
                entry["devices"], entry["error"] = _bounded(lister, cti, timeout_s)
        out.append(entry)
    return out


def uvc_devices() -> list[dict[str, str]]:
    """``/dev/video*`` nodes: ``path``, ``by_id``, ``name``."""
    import glob

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
    """Serial ports: ``device``, ``description``, ``vid_pid``, ``serial``, ``hwid``."""
    from serial.tools import list_ports

    out = []
    for port in sorted(list_ports.comports(), key=lambda p: p.device):
        vid_pid = f"{port.vid:04x}:{port.pid:04x}" if port.vid is not None and port.pid is not None else ""
        out.append({"device": port.device, "description": port.description or "",
                    "vid_pid": vid_pid, "serial": port.serial_number or "", "hwid": port.hwid or ""})
    return out


def load_usb_backend(spec: str) -> Any:
    """Import ``MODULE:ATTR``; call it when it is a class or function, to get the backend."""
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


def collect(args: argparse.Namespace, usb_backend: Any = None) -> dict[str, Any]:
    """Every section as plain data (what ``--json`` prints)."""
    if usb_backend is None and args.usb_backend:
        usb_backend = load_usb_backend(args.usb_backend)
    return {
        "genicam": genicam_devices(args.cti, not args.no_profiles, args.timeout),
        "uvc": uvc_devices(),
        "serial": serial_ports(),
        "usb": usb_devices(usb_backend),
    }


# -- output ----------------------------------------------------------------------------
def _print_text(found: dict[str, Any]) -> None:
    print("GenICam (GenTL producers)")
    if not found["genicam"]:
        print(f"  no producer named (profiles' camera.settings.cti, --cti, {GENTL_PATH_ENV})")
    for entry in found["genicam"]:
        print(f"  {entry['producer']}  ({', '.join(entry['named_by'])})")
        if entry["error"]:
            print(f"    {entry['error']}")
        elif not entry["devices"]:
            print("    no device")
        for i, d in enumerate(entry["devices"]):
            print(f"    [{i}] {d.get('vendor') or ''} {d.get('model') or ''}  serial "
                  f"{d.get('serial')}  id {d.get('id')}")
    print("UVC / V4L2")
    if not found["uvc"]:
        print("  no /dev/video* device")
    for d in found["uvc"]:
        extra = f"  {d['by_id']}" if d["by_id"] else ""
        print(f"  {d['path']}  {d['name']}{extra}")
    print("Serial ports")
    if not found["serial"]:
        print("  no serial port")
    for p in found["serial"]:
        vid = f"  USB {p['vid_pid']}" if p["vid_pid"] else ""
        ser = f"  serial {p['serial']}" if p["serial"] else ""
        print(f"  {p['device']}  {p['description']}{vid}{ser}")
    print("USB")
    usb = found["usb"]
    if usb["error"]:
        print(f"  {usb['error']}")
    elif not usb["devices"]:
        print("  no USB device")
    for d in usb["devices"]:
        names = " ".join(x for x in (d["manufacturer"], d["product"]) if x)
        ser = f"  serial {d['serial']}" if d["serial"] else ""
        bus = f"{d['bus']:03d}" if d["bus"] is not None else "?"
        addr = f"{d['address']:03d}" if d["address"] is not None else "?"
        print(f"  bus {bus} addr {addr}  {d['vid_pid']}  {names}{ser}")


def run(args: argparse.Namespace) -> int:
    found = collect(args)
    if args.json:
        print(json.dumps(found, indent=1, default=str))
    else:
        _print_text(found)
    return 0
