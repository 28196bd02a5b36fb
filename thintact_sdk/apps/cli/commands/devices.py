"""``thintact devices``: the cameras, serial ports and USB devices this machine can see.

The serial and USB sections come from :mod:`thintact_sdk.device.host_devices`
(:func:`~thintact_sdk.device.host_devices.list_devices`); this module parses, builds the
plugins' device listers and prints.

Sections
--------
one per device lister (the ``thintact_device_listers`` hook), first
    Each lister adds its own options to this command and returns its section, as data
    (``--json`` prints it under the lister's name) and as text lines. The GenICam plugin's
    lister ``genicam`` lists the GenTL producers that profiles, ``--cti`` and
    ``GENICAM_GENTL64_PATH`` name, and their devices. ``--timeout`` is the longest wait,
    in seconds, a lister gives one enumeration. The uvc plugin's lister ``uvc`` lists the
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
import json
from collections.abc import Callable
from typing import Any

from thintact_sdk.apps.cli.argtypes import positive_float
from thintact_sdk.device.host_devices import list_devices, load_usb_backend
from thintact_sdk.device.registry import get_registry
from thintact_sdk.errors import ThinTactError

CLI_DESCRIPTION = """\
List what this machine can see:
  plugins  each device lister's section (GenICam: the devices of each GenTL producer
           named by a profile's camera.settings.cti, by --cti, or by GENICAM_GENTL64_PATH;
           UVC: /dev/video* nodes with their /dev/v4l/by-id names)
  Serial   serial ports with USB VID:PID (use one as a profile's light.port)
  USB      every USB device by VID:PID with its strings (pyusb; --usb-backend injects one)
"""

#: A device lister as built by its component's factory: parsed arguments → (data, text lines).
Lister = Callable[[argparse.Namespace], tuple[Any, list[str]]]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("devices", help="list cameras (plugins' device listers), serial ports and USB devices",
                       description=CLI_DESCRIPTION,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--usb-backend", metavar="MODULE:ATTR",
                   help="pyusb backend to use (an IBackend, or a callable returning one)")
    p.add_argument("--timeout", type=positive_float, default=10.0, metavar="S",
                   help="longest wait for one enumeration of a device lister, e.g. one GenTL "
                        "producer (default 10)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run, device_listers=_device_listers(p))


def _device_listers(parser: argparse.ArgumentParser) -> dict[str, Lister | str]:
    """Name → lister (its options added to ``parser``), or → why it could not be built."""
    try:
        components = get_registry().components("device_lister")
    except ThinTactError:  # a broken plugin set still leaves the core's sections
        return {}
    listers: dict[str, Lister | str] = {}
    for name in sorted(components):
        try:
            listers[name] = get_registry().create("device_lister", name, parser)
        except ThinTactError:  # recorded on its plugin
            listers[name] = f"device lister {name!r} failed to build; `thintact plugins` shows why"
    return listers


def lister_sections(args: argparse.Namespace) -> dict[str, tuple[Any, list[str]]]:
    """Each device lister's section for ``args``: name → (data, text lines)."""
    out: dict[str, tuple[Any, list[str]]] = {}
    for name, lister in getattr(args, "device_listers", {}).items():
        if isinstance(lister, str):
            out[name] = ({"error": lister}, [name, f"  {lister}"])
        else:
            out[name] = lister(args)
    return out


def collect(args: argparse.Namespace, usb_backend: Any = None,
            sections: dict[str, tuple[Any, list[str]]] | None = None) -> dict[str, Any]:
    """Every section as plain data (what ``--json`` prints): the listers' (``sections``, else
    :func:`lister_sections`) and :func:`thintact_sdk.device.host_devices.list_devices`'s."""
    if usb_backend is None and args.usb_backend:
        usb_backend = load_usb_backend(args.usb_backend)
    if sections is None:
        sections = lister_sections(args)
    return list_devices({name: data for name, (data, _) in sections.items()}, usb_backend)


# -- output ----------------------------------------------------------------------------
def _print_text(found: dict[str, Any], lister_lines: list[str]) -> None:
    """The listers' lines, then the serial and USB sections of ``found``."""
    for line in lister_lines:
        print(line)
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
    usb_backend = load_usb_backend(args.usb_backend) if args.usb_backend else None
    sections = lister_sections(args)
    found = collect(args, usb_backend, sections)
    if args.json:
        print(json.dumps(found, indent=1, default=str))
    else:
        _print_text(found, [line for _, lines in sections.values() for line in lines])
    return 0
