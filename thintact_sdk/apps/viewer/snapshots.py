"""What the viewer's record and snapshot buttons write (docs/viewer.md#record-and-snapshot).

Both write under one output directory chosen when the viewer starts (``thintact view
--out DIR``, default :data:`DEFAULT_OUT` under the working directory); the request never
names a path. Names are made unique by the sensor's label, the local time and a counter,
and are claimed exclusively, so nothing is ever overwritten.

- A **snapshot** of a tactile frame is ``snapshot-<label>-<time>-f<frame id>-image.png``
  (the reconstruction, display units [0, 1] as 8-bit RGB) and ``...-depth.npy`` (the depth
  map, float32 mm, ``N × M``).
- A **recording** is a ``thintact-recording/1`` directory ``recording-<label>-<time>/`` of
  the live raw frames as ``thintact record --raw`` writes them (binned measurement, raw
  mosaic, frame id and timestamps), readable by the ``replay`` camera.
"""

from __future__ import annotations

import os
import re
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from thintact_sdk.device.cameras import to_measurement
from thintact_sdk.errors import OutputError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.raw_frames import save_raw_frame
from thintact_sdk.formats.recording import RecordingWriter, atomic_save_npy, atomic_write_bytes
from thintact_sdk.frames import RawFrame, TactileFrame

DEFAULT_OUT = "thintact-view"
"""Output directory of snapshots and recordings, relative to the working directory."""


def safe_label(text: str) -> str:
    """``text`` reduced to a file-name part: letters, digits, ``-`` and ``_`` (at most 40)."""
    return re.sub(r"[^A-Za-z0-9_-]+", "_", text).strip("_")[:40] or "sensor"


def _stamp() -> str:
    return time.strftime("%Y%m%d-%H%M%S")


def _output_dir(out: Path) -> Path:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"cannot create the viewer's output directory {out}: "
                          f"{err.strerror or err}") from None
    if not out.is_dir():
        raise OutputError(f"the viewer's output directory {out} is not a directory")
    return out


def _claim_dir(out: Path, stem: str) -> Path:
    """A new, empty directory ``out/stem`` (``stem-2``, ``stem-3``... when taken)."""
    for k in range(1, 10_000):
        path = out / (stem if k == 1 else f"{stem}-{k}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        except OSError as err:
            raise OutputError(f"cannot create {path}: {err.strerror or err}") from None
        return path
    raise OutputError(f"no free name for {stem} in {out}")


def _claim_file(out: Path, stem: str, suffixes: tuple[str, ...]) -> str:
    """A stem under which none of ``stem + suffix`` exists; the first is created empty,
    exclusively, so two snapshots in the same second never share a name."""
    for k in range(1, 10_000):
        name = stem if k == 1 else f"{stem}-{k}"
        if any((out / (name + s)).exists() for s in suffixes[1:]):
            continue
        try:
            fd = os.open(out / (name + suffixes[0]), os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            continue
        except OSError as err:
            raise OutputError(f"cannot write in {out}: {err.strerror or err}") from None
        os.close(fd)
        return name
    raise OutputError(f"no free name for {stem} in {out}")


def write_snapshot(out: Path, label: str, frame: TactileFrame) -> list[Path]:
    """Write ``frame``'s reconstruction (PNG) and depth map (``.npy``, float32 mm) under
    ``out``; returns the two paths.

    Raises
    ------
    OutputError
        ``out`` cannot be created or written.
    """
    out = _output_dir(out)
    suffixes = ("-image.png", "-depth.npy")
    stem = _claim_file(out, f"snapshot-{safe_label(label)}-{_stamp()}-f{int(frame.frame_id)}", suffixes)
    image = np.asarray(frame.image, np.float32)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    rgb = np.round(np.clip(np.nan_to_num(image, nan=0.0), 0.0, 1.0) * 255).astype(np.uint8)
    bgr = rgb[..., ::-1] if rgb.ndim == 3 else rgb
    ok, png = cv2.imencode(".png", np.ascontiguousarray(bgr))
    if not ok:
        raise OutputError(f"cannot encode the snapshot of frame {frame.frame_id} as PNG")
    paths = [out / (stem + s) for s in suffixes]
    try:
        atomic_write_bytes(paths[0], png.tobytes())
        atomic_save_npy(paths[1], np.asarray(frame.depth_mm, np.float32))
    except OSError as err:
        raise OutputError(f"cannot write the snapshot in {out}: {err.strerror or err}") from None
    return paths


class LiveRecorder:
    """Appends live raw frames to a new ``thintact-recording/1`` directory under ``out``.

    :meth:`write` is called by the frame loop and :meth:`close` by whoever stops the
    recording; both are safe to call from different threads. A write failure (disk full)
    closes the recorder and keeps the message in :attr:`error`; every frame written
    before it stays in the recording.

    Raises
    ------
    OutputError
        ``out`` cannot be created or written.
    """

    def __init__(self, out: Path, label: str, profile: Profile) -> None:
        self.path = _claim_dir(_output_dir(out), f"recording-{safe_label(label)}-{_stamp()}")
        self.profile = profile
        self.frames = 0
        self.error: str | None = None
        self._lock = threading.Lock()
        self._writer: RecordingWriter | None = RecordingWriter(self.path, profile)

    @property
    def active(self) -> bool:
        return self._writer is not None

    def write(self, raw: RawFrame) -> None:
        """Add ``raw`` (binned measurement + raw mosaic + its ids and timestamps)."""
        with self._lock:
            if self._writer is None:
                return
            try:
                meas = to_measurement(raw, self.profile)
                extra: dict[str, Any] = {"timestamp_ns": int(raw.timestamp_ns), "frame_id": int(raw.frame_id),
                         "exposure_us": raw.exposure_us}
                extra.update(save_raw_frame(self.path, self.frames, raw))
                data = meas.data
                if data.size and np.all(np.isfinite(data)) and data.min() >= 0 and data.max() <= 65535 \
                        and np.array_equal(data, np.round(data)):
                    data = data.astype(np.uint16)
                self._writer.add(data, label=f"frame{self.frames:06d}", **extra)
                self.frames += 1
            except Exception as err:  # noqa: BLE001 - a disk or data fault ends this recording only
                self.error = f"recording {self.path} stopped after {self.frames} frames: {err}"
                self._writer = None

    def close(self) -> None:
        """Stop recording (every frame is already in the manifest). Safe to call twice."""
        with self._lock:
            self._writer = None
