"""Reading and writing ``thintact-recording/1`` directories (CONTRACTS §3).

Layout::

    manifest.json
    profile.json
    scenes/000_white.npy         float32 N×M×C, display values in [0, 1]
    measurements/000_white.npy   uint16 or float32 R×S×C raw DN (black level not removed)

Frames may omit ``scene``; scene and measurement files may also be 8/16-bit PNG or TIFF.
Every file the writer produces is written atomically (temp file + rename) and the
manifest is rewritten after each frame, so a killed writer leaves a valid recording
holding every frame completed before the kill.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import ProfileError, RecordingError
from thintact_sdk.profile import Profile, read_profile_file, write_profile

RECORDING_FORMAT = "thintact-recording/1"
_IMAGE_SUFFIXES = (".png", ".tif", ".tiff")


@dataclass
class RecordingFrame:
    """One manifest entry; paths are relative to the recording directory."""

    measurement: str
    scene: str | None = None
    label: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = dict(self.extra)
        if self.scene is not None:
            d["scene"] = self.scene
        d["measurement"] = self.measurement
        if self.label is not None:
            d["label"] = self.label
        return d


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see either the old file or the whole new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_save_npy(path: Path, array: np.ndarray) -> None:
    """``np.save`` made atomic (temp file in the same directory, fsync, rename)."""
    import io

    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    atomic_write_bytes(path, buf.getvalue())


def _read_image_file(path: Path, is_scene: bool) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RecordingError(f"cannot read image {path}")
    if img.ndim == 3:
        img = img[..., ::-1] if img.shape[2] == 3 else img[..., [2, 1, 0, 3]][..., :3]
    else:
        img = img[..., None]
    if is_scene:
        scale = 255.0 if img.dtype == np.uint8 else 65535.0 if img.dtype == np.uint16 else 1.0
        return (img.astype(np.float32) / np.float32(scale)).copy()
    return np.ascontiguousarray(img)


def read_array(path: Path, is_scene: bool) -> np.ndarray:
    """Read a scene (→ float32 in [0, 1]) or measurement (→ as stored) from .npy/.png/.tif."""
    if not path.is_file():
        raise RecordingError(f"missing file {path}")
    if path.suffix.lower() == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as err:
            raise RecordingError(f"cannot read {path} (truncated or not a .npy file): {err}") from None
        if is_scene:
            arr = arr.astype(np.float32, copy=False)
        return arr
    if path.suffix.lower() in _IMAGE_SUFFIXES:
        return _read_image_file(path, is_scene)
    raise RecordingError(f"unsupported file type {path.suffix!r} for {path} (npy, png, tif)")


class Recording:
    """A ``thintact-recording/1`` directory opened for reading.

    Parameters
    ----------
    root
        The recording directory.
    profile
        Optional profile to use instead of the recording's own.
    """

    def __init__(self, root: str | os.PathLike[str], profile: Profile | None = None) -> None:
        self.root = Path(root)
        mpath = self.root / "manifest.json"
        if not mpath.is_file():
            raise RecordingError(f"{self.root} is not a recording: no manifest.json")
        try:
            manifest = json.loads(mpath.read_text(encoding="utf-8"))
        except json.JSONDecodeError as err:
            raise RecordingError(f"{mpath}: invalid JSON ({err})") from None
        if manifest.get("format") != RECORDING_FORMAT:
            raise RecordingError(
                f"{mpath}: format {manifest.get('format')!r} is not {RECORDING_FORMAT!r}"
            )
        self.manifest = manifest
        if profile is None:
            ppath = self.root / manifest.get("profile", "profile.json")
            try:
                profile = read_profile_file(ppath)
            except ProfileError as err:
                raise RecordingError(f"recording {self.root}: {err}") from None
        self.profile = profile
        frames = manifest.get("frames")
        if not isinstance(frames, list):
            raise RecordingError(f"{mpath}: 'frames' must be a list")
        self.frames: list[RecordingFrame] = []
        for i, fr in enumerate(frames):
            if not isinstance(fr, dict) or "measurement" not in fr:
                raise RecordingError(f"{mpath}: frame {i} has no 'measurement'")
            extra = {k: v for k, v in fr.items() if k not in ("scene", "measurement", "label")}
            self.frames.append(RecordingFrame(fr["measurement"], fr.get("scene"), fr.get("label"), extra))

    def __len__(self) -> int:
        return len(self.frames)

    def measurement(self, i: int) -> np.ndarray:
        """Frame ``i``'s measurement, ``R × S × C`` raw DN as stored (uint16 or float32)."""
        arr = read_array(self.root / self.frames[i].measurement, is_scene=False)
        exp = (self.profile.sensor.rows, self.profile.sensor.cols)
        if arr.shape[:2] != exp:
            raise RecordingError(
                f"{self.frames[i].measurement}: shape {arr.shape} does not match the profile's "
                f"sensor {exp[0]}×{exp[1]}"
            )
        return arr

    def scene(self, i: int) -> np.ndarray | None:
        """Frame ``i``'s scene, ``N × M × C`` float32 in [0, 1], or None for unknown scenes."""
        s = self.frames[i].scene
        if s is None:
            return None
        arr = read_array(self.root / s, is_scene=True)
        exp = (self.profile.scene.rows, self.profile.scene.cols)
        if arr.shape[:2] != exp:
            raise RecordingError(
                f"{s}: shape {arr.shape} does not match the profile's scene {exp[0]}×{exp[1]}"
            )
        return arr

    def __iter__(self) -> Iterator[tuple[RecordingFrame, np.ndarray | None, np.ndarray]]:
        for i, fr in enumerate(self.frames):
            yield fr, self.scene(i), self.measurement(i)


class RecordingWriter:
    """Writes a ``thintact-recording/1`` directory frame by frame, atomically.

    Opening an existing recording appends to it (resume): frames already in its manifest
    are kept and :meth:`has_label` tells a resuming writer what is already done.
    """

    def __init__(self, root: str | os.PathLike[str], profile: Profile) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        (self.root / "scenes").mkdir(exist_ok=True)
        (self.root / "measurements").mkdir(exist_ok=True)
        self.profile = profile
        self.frames: list[RecordingFrame] = []
        mpath = self.root / "manifest.json"
        if mpath.is_file():
            existing = Recording(self.root, profile=profile)
            self.frames = list(existing.frames)
        ppath = self.root / "profile.json"
        if not ppath.is_file():
            write_profile(profile, ppath)
        self._write_manifest()

    def has_label(self, label: str) -> bool:
        """True if a frame with ``label`` is already recorded."""
        return any(f.label == label for f in self.frames)

    def labels(self) -> list[str]:
        return [f.label for f in self.frames if f.label is not None]

    def add(
        self,
        measurement: np.ndarray,
        scene: np.ndarray | None = None,
        label: str | None = None,
        **extra: Any,
    ) -> RecordingFrame:
        """Append one frame: files first (atomically), then the manifest.

        Parameters
        ----------
        measurement
            ``R × S × C`` uint16 or float32 raw DN.
        scene
            ``N × M × C`` float32 display values, or None for an unknown scene.
        label
            Short name; also used in the file names (``007_<label>.npy``).
        extra
            JSON-serialisable per-frame metadata (timestamp_ns, frame_id, exposure_us, ...).
        """
        idx = len(self.frames)
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in (label or f"frame{idx}"))
        stem = f"{idx:03d}_{safe}" if idx < 1000 else f"{idx:06d}_{safe}"
        mrel = f"measurements/{stem}.npy"
        if measurement.dtype not in (np.uint16, np.float32):
            measurement = measurement.astype(np.float32)
        atomic_save_npy(self.root / mrel, measurement)
        srel = None
        if scene is not None:
            srel = f"scenes/{stem}.npy"
            atomic_save_npy(self.root / srel, scene.astype(np.float32, copy=False))
        fr = RecordingFrame(mrel, srel, label, dict(extra))
        self.frames.append(fr)
        self._write_manifest()
        return fr

    def _write_manifest(self) -> None:
        manifest = {
            "format": RECORDING_FORMAT,
            "profile": "profile.json",
            "frames": [f.to_json() for f in self.frames],
        }
        atomic_write_bytes(self.root / "manifest.json", (json.dumps(manifest, indent=1) + "\n").encode())
