"""What a ``uvc`` camera's ``device`` setting names: a V4L2 device or a file source.

- an integer (or digit string): V4L2 device index (``/dev/video<N>``);
- ``/dev/video*`` or a ``/dev/v4l/by-id/...`` / ``by-path`` link: that device;
- a path containing ``%`` (``img_%04d.png``): an image sequence;
- any other path: a video file (lossless FFV1 in .mkv/.avi or PNG-in-AVI for exact data).
"""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass
from pathlib import Path

from thintact_sdk.errors import DeviceNotFoundError


@dataclass(frozen=True)
class Source:
    """A resolved source: ``kind`` is ``device``, ``sequence`` or ``video``."""

    kind: str
    target: str | int
    """Device index or path handed to OpenCV."""
    label: str
    """What the user named (for messages)."""

    @property
    def is_live(self) -> bool:
        return self.kind == "device"


def resolve_source(device: str | int | os.PathLike[str], base: Path | None = None) -> Source:
    """Resolve the ``device`` setting (relative file paths are taken relative to ``base``).

    Raises
    ------
    DeviceNotFoundError
        When the device node, video file or first image of a sequence does not exist.
    """
    if isinstance(device, int) or (isinstance(device, str) and device.isdigit()):
        index = int(device)
        node = f"/dev/video{index}"
        if not os.path.exists(node):
            raise DeviceNotFoundError(
                f"no UVC camera {index}: {node} does not exist ({_present()})"
            )
        return Source("device", index, node)
    text = str(device)
    if text.startswith("/dev/"):
        if not os.path.exists(text):
            raise DeviceNotFoundError(f"no UVC camera at {text} ({_present()})")
        real = os.path.realpath(text)
        return Source("device", real, text)
    path = Path(text).expanduser()
    if not path.is_absolute() and base is not None:
        path = base / path
    if "%" in path.name:
        try:
            first = str(path) % 0
            second = str(path) % 1
        except (TypeError, ValueError):
            raise DeviceNotFoundError(f"bad image-sequence pattern {text!r} (use e.g. img_%04d.png)") from None
        if not (os.path.exists(first) or os.path.exists(second)):
            raise DeviceNotFoundError(f"image sequence {path}: neither {first} nor {second} exists")
        return Source("sequence", str(path), text)
    if not path.exists() or path.is_dir():
        raise DeviceNotFoundError(f"video file {path} not found")
    return Source("video", str(path), text)


def _present() -> str:
    nodes = sorted(glob.glob("/dev/video*"))
    return "present: " + ", ".join(nodes) if nodes else "no /dev/video* device on this machine"

