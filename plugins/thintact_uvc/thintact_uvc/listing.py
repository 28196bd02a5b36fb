"""The UVC section of ``thintact devices``: the ``/dev/video*`` nodes of this machine.

This is the ``uvc`` component of the ``thintact_device_listers`` hook: the command builds
it with its parser (no options of its own) and calls it with the parsed arguments; it
returns its section as data (``--json`` prints it under ``uvc``) and as text lines. A
machine without V4L2 devices gives an empty list, never an error.
"""

from __future__ import annotations

import argparse
import glob
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any


def video_nodes() -> list[dict[str, str]]:
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


def section_lines(nodes: list[dict[str, str]]) -> list[str]:
    """The text of the section: a heading, then one line per node (path, card name, by-id link)."""
    lines = ["UVC / V4L2"]
    if not nodes:
        lines.append("  no /dev/video* device")
    for d in nodes:
        extra = f"  {d['by_id']}" if d["by_id"] else ""
        lines.append(f"  {d['path']}  {d['name']}{extra}")
    return lines


def device_lister(parser: argparse.ArgumentParser) -> Callable[[argparse.Namespace], tuple[Any, list[str]]]:
    """The lister for ``thintact devices`` (``parser`` gets no option from this section)."""

    def lister(args: argparse.Namespace) -> tuple[Any, list[str]]:
        nodes = video_nodes()
        return nodes, section_lines(nodes)

    return lister
