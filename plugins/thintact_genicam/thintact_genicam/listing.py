"""The GenICam section of ``thintact devices``: which GenTL producers are named, and their devices.

A producer (``.cti`` file) is named by a profile (``camera.settings.cti`` of a shipped or
user profile whose ``camera.plugin`` is ``genicam``), by ``--cti PATH`` on the command line,
or by ``GENICAM_GENTL64_PATH`` (entries separated by ``os.pathsep``; a directory stands for
its ``*.cti`` files, anything else for itself). Producers are only loaded when named;
nothing is broadcast on a network by this listing itself.

This is the ``genicam`` component of the ``thintact_device_listers`` hook: :func:`add_arguments`
adds ``--cti`` and ``--no-profiles`` to the ``devices`` parser, and :func:`list_section`
returns the section, as data and as text lines.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from thintact_genicam.producers import GENTL_PATH_ENV, list_devices
from thintact_sdk.errors import ThinTactError
from thintact_sdk.plugin_support import available_profiles, load_profile

DEFAULT_TIMEOUT_S = 10.0
"""Longest wait (s) for one producer's enumeration when the parser gives none."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of this section on ``thintact devices``."""
    parser.add_argument("--cti", action="append", default=[], metavar="PATH",
                        help="also enumerate this GenTL producer (repeatable)")
    parser.add_argument("--no-profiles", action="store_true",
                        help="do not load the GenTL producers named by profiles")


def genicam_producers(extra: list[str], from_profiles: bool = True) -> dict[str, list[str]]:
    """Producer path (resolved) → what named it: ``profile NAME``, ``--cti``, ``GENICAM_GENTL64_PATH``.

    Profiles that cannot be read are skipped; ``extra`` are the ``--cti`` paths.
    """
    named: dict[str, list[str]] = {}
    if from_profiles:
        for name, path in sorted(available_profiles().items()):
            try:
                prof = load_profile(path)
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


def bounded(fn: Callable[[str], list[dict[str, Any]]], arg: str,
            timeout_s: float) -> tuple[list[dict[str, Any]], str | None]:
    """``(fn(arg), None)`` run on a worker thread, or ``([], why)``.

    A producer still enumerating after ``timeout_s`` seconds is reported, not waited for
    (its thread is left to finish on its own); a :class:`ThinTactError`, or harvesters
    missing, becomes ``why``.
    """
    pool = cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="gentl-enum")
    future = pool.submit(fn, arg)
    try:
        return future.result(timeout=timeout_s), None
    except cf.TimeoutError:
        return [], f"the producer did not finish enumerating within {timeout_s:.0f} s"
    except ThinTactError as err:
        return [], str(err)
    except ImportError as err:
        return [], f"cannot enumerate GenTL producers: {err} (install harvesters)"
    finally:
        pool.shutdown(wait=False)


def genicam_devices(extra: list[str], from_profiles: bool = True,
                    timeout_s: float = DEFAULT_TIMEOUT_S) -> list[dict[str, Any]]:
    """One entry per named producer: ``producer`` (path), ``named_by`` (list of str),
    ``devices`` (:func:`thintact_genicam.producers.list_devices` entries) and ``error``
    (str, or None when it enumerated)."""
    out: list[dict[str, Any]] = []
    for cti, named_by in genicam_producers(extra, from_profiles).items():
        entry: dict[str, Any] = {"producer": cti, "named_by": named_by, "devices": [],
                                 "error": None}
        if not Path(cti).is_file():
            entry["error"] = "producer file not found (install the camera vendor's GenTL SDK)"
        else:
            entry["devices"], entry["error"] = bounded(list_devices, cti, timeout_s)
        out.append(entry)
    return out


def text_lines(found: list[dict[str, Any]]) -> list[str]:
    """The section as ``thintact devices`` prints it: a heading, then two-space indented lines."""
    lines = ["GenICam (GenTL producers)"]
    if not found:
        lines.append(f"  no producer named (profiles' camera.settings.cti, --cti, {GENTL_PATH_ENV})")
    for entry in found:
        lines.append(f"  {entry['producer']}  ({', '.join(entry['named_by'])})")
        if entry["error"]:
            lines.append(f"    {entry['error']}")
        elif not entry["devices"]:
            lines.append("    no device")
        for i, d in enumerate(entry["devices"]):
            lines.append(f"    [{i}] {d.get('vendor') or ''} {d.get('model') or ''}  serial "
                         f"{d.get('serial')}  id {d.get('id')}")
    return lines


def list_section(args: argparse.Namespace) -> tuple[list[dict[str, Any]], list[str]]:
    """The section for parsed ``args`` (``cti``, ``no_profiles``, and ``timeout`` in seconds
    per producer when the parser has it): ``(entries of genicam_devices, text lines)``."""
    found = genicam_devices(list(getattr(args, "cti", []) or []),
                            not getattr(args, "no_profiles", False),
                            float(getattr(args, "timeout", None) or DEFAULT_TIMEOUT_S))
    return found, text_lines(found)


def device_lister(parser: argparse.ArgumentParser) -> Callable[
        [argparse.Namespace], tuple[list[dict[str, Any]], list[str]]]:
    """The ``thintact_device_listers`` factory: add this section's options, return its lister."""
    add_arguments(parser)
    return list_section
