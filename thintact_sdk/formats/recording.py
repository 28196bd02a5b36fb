"""Reading and writing ``thintact-recording/1`` directories (CONTRACTS §3).

Layout::

    manifest.json
    profile.json
    scenes/000_white.npy         float32 N×M×C, display values in [0, 1]
    measurements/000_white.npy   uint16 or float32 R×S×C raw DN (black level not removed)

Frames may omit ``scene``; scene and measurement files may also be 8/16-bit PNG or TIFF.

Optional extension (CONTRACTS §3 allows optional fields): a measurement may also be an 8-bit
JPEG (``.jpg``/``.jpeg``) or one frame of an MJPEG (or other ffmpeg-readable) video
(``.avi``/``.mjpeg``/``.mjpg``/``.mkv``/``.mov``/``.mp4``, with the frame's index in the
optional field ``video_frame``), as a camera that encodes its output delivers it. Such frames
are *tone-mapped* by default (optional field ``tone_mapped``, default true for JPEG and video,
false otherwise): when the profile declares ``sensor.tone_curve`` the reader undoes it
(:func:`thintact_sdk.pixels.tone_curve.linearize`) and returns float32 linear DN. Scenes stay
lossless (npy/PNG/TIFF): a JPEG scene is refused, compression would corrupt the ground truth.
Every file the writer produces is written atomically (temp file + rename) and the
manifest is rewritten after each frame, so a killed writer leaves a valid recording
holding every frame completed before the kill; the temp files such a kill leaves behind
are never listed in the manifest and are removed when the recording is opened for writing.

Reading is strict, so that nothing downstream computes on bad data: every file a manifest
names must lie inside the recording directory (no ``..``, absolute paths or symlinks out),
measurements must be finite, non-negative numbers (not bool or text), ``R × S × C`` with the
profile's channels, scenes finite display values in [0, 1], and per-frame metadata
(``frame_id``, ``timestamp_ns``, ``exposure_us`` ...) of the right type and sign. Each
violation is a :class:`~thintact_sdk.errors.RecordingError` naming the frame and field.

Each frame file is read and checked once per :class:`Recording`: a command opens one and hands
it to every stage, which all see the same cached, read-only arrays (:meth:`Recording.measurement`).
Every read goes through :func:`read_frame_file`.
"""

from __future__ import annotations

import json
import math
import mmap
import os
import tempfile
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from thintact_sdk.errors import ProfileError, RecordingError
from thintact_sdk.formats import safe_json
from thintact_sdk.formats.profiles import Profile, read_profile_file
from thintact_sdk.formats.safe_arrays import read_npy
from thintact_sdk.formats.safe_images import opencv_path
from thintact_sdk.pixels.tone_curve import inline_table

RECORDING_FORMAT = "thintact-recording/1"
_IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
_JPEG_SUFFIXES = (".jpg", ".jpeg")
_VIDEO_SUFFIXES = (".avi", ".mjpeg", ".mjpg", ".mkv", ".mov", ".mp4")
TONE_MAPPED_FIELD = "tone_mapped"
VIDEO_FRAME_FIELD = "video_frame"
_NUMERIC_KINDS = "uif"
"""dtype kinds a scene or measurement may have (unsigned, signed integer, float)."""
_COUNT_FIELDS = ("frame_id", "timestamp_ns", "device_timestamp_ns", "dropped_before", VIDEO_FRAME_FIELD)
"""Per-frame metadata that must be a non-negative integer when present."""
SCENE_TOLERANCE = 1e-6
"""Scene values may exceed [0, 1] by this much (float rounding), no more."""
MAP_FROM_BYTES = 4096
"""An ``.npy`` frame file of at least this many bytes (one page) is memory-mapped read-only
after its header is checked (:func:`~thintact_sdk.formats.safe_arrays.read_npy`) instead of
read into memory."""
HELD_BYTES = 64 * 2**20
"""Bytes of decoded frames (PNG, TIFF, JPEG, video, linearised, converted) one
:class:`Recording` keeps in memory; beyond it they are kept in a temporary ``.npy`` file of
the Recording's own (removed with it) and mapped from there."""
MAX_OPEN_MAPS = 128
"""Mapped frames one :class:`Recording` keeps open at once (each mapping holds a file
descriptor, and a paper-size calibration has about two thousand frame files). A frame whose
mapping was let go is mapped again when asked for, after checking that its file is the one
read (same inode, size and modification time); it is not read or checked again."""
MAX_OPEN_MAP_BYTES = 256 * 2**20
"""Bytes of mapped frames one :class:`Recording` keeps open at once (at least one frame):
the pages of a frame read through an open mapping count in the process's resident memory
until it is let go (128 paper-size frames were 1 GB of it). Mapping a frame again costs a
``stat`` and a header read, not a read of the frame."""


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

    from thintact_sdk.formats.safe_images import read_image

    img = read_image(path, cv2.IMREAD_UNCHANGED, RecordingError)
    if img.ndim == 3:
        img = img[..., ::-1] if img.shape[2] == 3 else img[..., [2, 1, 0, 3]][..., :3]
    else:
        img = img[..., None]
    if is_scene:
        scale = 255.0 if img.dtype == np.uint8 else 65535.0 if img.dtype == np.uint16 else 1.0
        return (img.astype(np.float32) / np.float32(scale)).copy()
    return np.ascontiguousarray(img)


def is_encoded(path: Path) -> bool:
    """Whether ``path`` is a camera-encoded (JPEG or video) measurement file."""
    return path.suffix.lower() in _JPEG_SUFFIXES + _VIDEO_SUFFIXES


def read_video_frame(path: Path, index: int, gray: bool) -> np.ndarray:
    """Frame ``index`` of a video file (MJPEG etc., through OpenCV's ffmpeg), ``H × W × 3`` RGB
    uint8, or ``H × W`` when ``gray`` (a monochrome sensor).

    Raises
    ------
    RecordingError
        The file is missing or unreadable, or holds fewer than ``index + 1`` frames.
    """
    import cv2

    if not path.is_file():
        raise RecordingError(f"missing file {path}")
    cap = cv2.VideoCapture(opencv_path(path, RecordingError))
    try:
        if not cap.isOpened():
            raise RecordingError(f"cannot open video {path}")
        from thintact_sdk.formats.safe_images import check_video_frames

        check_video_frames(cap, path, RecordingError)
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if index >= count > 0:
            raise RecordingError(f"{path}: video_frame {index} but the video holds {count} frame(s)")
        cap.set(cv2.CAP_PROP_POS_FRAMES, index)
        ok, img = cap.read()
    finally:
        cap.release()
    if not ok or img is None:
        raise RecordingError(f"{path}: cannot decode video frame {index}")
    if gray:
        return np.ascontiguousarray(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    return np.ascontiguousarray(img[..., ::-1])


def read_array(path: Path, is_scene: bool, *, mmap: bool = False) -> np.ndarray:
    """Read a scene (→ float32 in [0, 1]) or measurement (→ as stored) from .npy/.png/.tif
    (measurements also .jpg/.jpeg); with ``mmap`` an ``.npy`` file is mapped read-only after
    its header is checked (a scene stored as float32 stays mapped)."""
    if not path.is_file():
        raise RecordingError(f"missing file {path}")
    if path.suffix.lower() in _JPEG_SUFFIXES:
        if is_scene:
            raise RecordingError(f"{path}: a scene must be lossless (npy, png, tif); JPEG "
                                 "compression would corrupt the ground truth")
        return _read_image_file(path, is_scene)
    if path.suffix.lower() == ".npy":
        arr = read_npy(path, what="scene" if is_scene else "measurement", error=RecordingError,
                       kinds=_NUMERIC_KINDS, mmap=mmap)
        if is_scene:
            arr = arr.astype(np.float32, copy=False)
        return arr
    if path.suffix.lower() in _IMAGE_SUFFIXES:
        return _read_image_file(path, is_scene)
    if path.suffix.lower() in _VIDEO_SUFFIXES:
        raise RecordingError(f"{path}: a video needs the frame's 'video_frame' index")
    raise RecordingError(f"unsupported file type {path.suffix!r} for {path} (npy, png, tif; "
                         "measurements also jpg and MJPEG video)")


def read_frame_file(path: Path, *, is_scene: bool, video_frame: int | None = None, gray: bool = False,
                    mmap: bool = False) -> np.ndarray:
    """One scene or measurement file of a recording, as stored (nothing checked but the file).

    The only function through which :class:`Recording` reads a frame file. ``video_frame``
    names the frame of a video file (``gray``: of a monochrome sensor,
    :func:`read_video_frame`); otherwise :func:`read_array` (``mmap``: map an ``.npy`` file).

    Raises
    ------
    RecordingError
        The file is missing, unreadable or damaged (named).
    """
    if video_frame is not None:
        return read_video_frame(path, video_frame, gray)
    return read_array(path, is_scene, mmap=mmap)


@dataclass(frozen=True)
class _Mapped:
    """A kept frame that lives in a mapped ``.npy`` file (see :data:`MAX_OPEN_MAPS`)."""

    path: Path
    stamp: tuple[int, int, int]
    shape: tuple[int, ...]
    dtype: np.dtype


def _stamp(path: Path) -> tuple[int, int, int]:
    """``(inode, size, mtime_ns)`` of ``path``: what tells a replaced or changed file."""
    st = path.stat()
    return st.st_ino, st.st_size, st.st_mtime_ns


def _is_mapped(arr: np.ndarray) -> bool:
    """Whether ``arr`` is (a view of) a memory-mapped file."""
    base: object = arr
    while isinstance(base, np.ndarray):
        base = base.base
    return isinstance(base, mmap.mmap)


class Recording:
    """A ``thintact-recording/1`` directory opened for reading.

    The one object a command opens on a recording and hands to every stage: each frame's
    files are read and checked on first use (:meth:`measurement`, :meth:`scene`) and kept, so
    every file is read once however many stages look at the frame. The arrays returned are
    read-only and shared; copy before changing one. Memory: ``.npy`` frames (from
    :data:`MAP_FROM_BYTES`) are memory-mapped, so the page cache holds them, not the process;
    decoded frames are held up to :data:`HELD_BYTES`, then mapped from a temporary file; at
    most :data:`MAX_OPEN_MAPS` mappings (:data:`MAX_OPEN_MAP_BYTES`) are open at once.

    Parameters
    ----------
    root
        The recording directory.
    profile
        Optional profile to use instead of the recording's own.
    allow_empty
        Accept a manifest without frames (a writer resuming a recording); readers leave it
        False so that an empty recording is an error, not an empty result.

    Raises
    ------
    RecordingError
        When the manifest is missing or malformed, names a file outside the directory, or a
        frame's metadata has the wrong type (the frame and field are named).
    """

    def __init__(
        self, root: str | os.PathLike[str], profile: Profile | None = None, *, allow_empty: bool = False
    ) -> None:
        self.root = Path(root)
        mpath = self.root / "manifest.json"
        if not mpath.is_file():
            raise RecordingError(f"{self.root} is not a recording: no manifest.json")
        try:
            text = mpath.read_text(encoding="utf-8")
        except UnicodeDecodeError as err:
            raise RecordingError(f"{mpath}: invalid JSON ({err})") from None
        manifest = safe_json.loads(text, mpath, RecordingError)
        if not isinstance(manifest, dict):
            raise RecordingError(f"{mpath}: expected a JSON object, got {type(manifest).__name__}")
        if manifest.get("format") != RECORDING_FORMAT:
            raise RecordingError(
                f"{mpath}: format {manifest.get('format')!r} is not {RECORDING_FORMAT!r}"
            )
        self.manifest = manifest
        if profile is None:
            prel = manifest.get("profile", "profile.json")
            if not isinstance(prel, str) or not prel:
                raise RecordingError(f"{mpath}: 'profile' must be a file name, got {prel!r}")
            ppath = self._inside(prel, "manifest field 'profile'")
            try:
                profile = read_profile_file(ppath)
            except (ProfileError, UnicodeDecodeError) as err:
                raise RecordingError(f"recording {self.root}: {err}") from None
        self.profile = profile
        frames = manifest.get("frames")
        if not isinstance(frames, list):
            raise RecordingError(f"{mpath}: 'frames' must be a list")
        if not frames and not allow_empty:
            raise RecordingError(f"recording {self.root} holds no frames")
        self.frames: list[RecordingFrame] = [self._frame(i, fr, mpath) for i, fr in enumerate(frames)]
        self._kept: dict[tuple[str, int], np.ndarray | _Mapped | None] = {}
        self._open_maps: OrderedDict[tuple[str, int], np.ndarray] = OrderedDict()
        self._open_map_bytes = 0
        self._held_bytes = 0
        self._spill: tempfile.TemporaryDirectory[str] | None = None
        self._lock = threading.RLock()

    def _inside(self, rel: str, what: str) -> Path:
        """``root / rel`` after checking that it stays inside the recording directory."""
        if Path(rel).is_absolute() or "\x00" in rel:
            raise RecordingError(f"recording {self.root}: {what} {rel!r} must be a path relative "
                                 "to the recording directory")
        path = self.root / rel
        try:
            inside = path.resolve().is_relative_to(self.root.resolve())
        except (OSError, RuntimeError, ValueError) as err:  # symlink loops, bad names
            raise RecordingError(f"recording {self.root}: {what} {rel!r}: {err}") from None
        if not inside:
            raise RecordingError(f"recording {self.root}: {what} {rel!r} points outside the "
                                 "recording directory (.. or a symlink); refused")
        return path

    def _frame(self, i: int, fr: object, mpath: Path) -> RecordingFrame:
        """Manifest entry ``i`` checked field by field."""
        if not isinstance(fr, dict):
            raise RecordingError(f"{mpath}: frame {i} is not an object")
        where = f"{mpath}: frame {i}"
        meas = fr.get("measurement")
        if not isinstance(meas, str) or not meas:
            raise RecordingError(f"{where}: 'measurement' must be a file name, got {meas!r}")
        self._inside(meas, f"frame {i} 'measurement'")
        scene = fr.get("scene")
        if scene is not None:
            if not isinstance(scene, str) or not scene:
                raise RecordingError(f"{where}: 'scene' must be a file name or absent, got {scene!r}")
            self._inside(scene, f"frame {i} 'scene'")
        label = fr.get("label")
        if label is not None and not isinstance(label, str):
            raise RecordingError(f"{where}: 'label' must be a string, got {label!r}")
        if label is not None:  # JSON may escape lone surrogates, which no text renderer takes
            label = label.encode("utf-8", "backslashreplace").decode("utf-8")
        extra = {k: v for k, v in fr.items() if k not in ("scene", "measurement", "label")}
        for key in _COUNT_FIELDS:
            v = extra.get(key)
            if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < 0):
                raise RecordingError(f"{where}: {key!r} must be a non-negative integer, got {v!r}")
        exposure = extra.get("exposure_us")
        if exposure is not None and not (_is_number(exposure) and exposure > 0):
            raise RecordingError(f"{where}: 'exposure_us' must be a positive number of microseconds, "
                                 f"got {exposure!r}")
        tone = extra.get(TONE_MAPPED_FIELD)
        if tone is not None and not isinstance(tone, bool):
            raise RecordingError(f"{where}: {TONE_MAPPED_FIELD!r} must be true or false, got {tone!r}")
        if Path(meas).suffix.lower() in _VIDEO_SUFFIXES and VIDEO_FRAME_FIELD not in extra:
            raise RecordingError(f"{where}: measurement {meas!r} is a video; name the frame with "
                                 f"'{VIDEO_FRAME_FIELD}' (0-based index)")
        for key in ("gain_db", "saturated_fraction"):
            v = extra.get(key)
            if v is not None and not _is_number(v):
                raise RecordingError(f"{where}: {key!r} must be a finite number, got {v!r}")
        return RecordingFrame(meas, scene, label, extra)

    def __len__(self) -> int:
        return len(self.frames)

    def _name(self, i: int) -> str:
        fr = self.frames[i]
        return f"frame {i} ({fr.label})" if fr.label else f"frame {i}"

    def tone_mapped(self, i: int) -> bool:
        """Whether frame ``i``'s stored values are camera-encoded (``tone_mapped`` field;
        default true for JPEG and video files, false otherwise)."""
        fr = self.frames[i]
        flag = fr.extra.get(TONE_MAPPED_FIELD)
        return bool(flag) if flag is not None else is_encoded(Path(fr.measurement))

    def _map(self, path: Path) -> bool:
        """Whether to memory-map frame file ``path`` (see the class docstring)."""
        if path.suffix.lower() != ".npy":
            return False
        try:
            return path.stat().st_size >= MAP_FROM_BYTES
        except OSError:
            return False  # the read names the file

    def _frame_array(self, key: tuple[str, int],
                     read: Callable[[int], tuple[np.ndarray, Path] | None]) -> np.ndarray | None:
        """Frame ``key``'s kept array, read (``read(index)``: the checked array and its file)
        on first use; see the class docstring. Thread-safe: the calibration's stages read one
        recording from two threads."""
        with self._lock:
            if key not in self._kept:
                got = read(key[1])
                self._kept[key] = None if got is None else self._keep(key, *got)
            kept = self._kept[key]
            if isinstance(kept, _Mapped):
                return self._mapping(key, kept)
            return kept

    def _keep(self, key: tuple[str, int], arr: np.ndarray, path: Path) -> np.ndarray | _Mapped:
        """``arr`` (read from ``path``) as the Recording keeps it: held, or mapped."""
        if not _is_mapped(arr):
            if self._held_bytes + arr.nbytes <= HELD_BYTES:
                self._held_bytes += arr.nbytes
                arr.flags.writeable = False
                return arr
            if self._spill is None:
                self._spill = tempfile.TemporaryDirectory(prefix="thintact-frames-")
            path = Path(self._spill.name) / f"{key[0]}{key[1]}.npy"
            np.save(path, np.ascontiguousarray(arr), allow_pickle=False)
            arr = np.load(path, mmap_mode="r", allow_pickle=False)
        view = np.asarray(arr)  # a plain view of the read-only map
        self._remember(key, view)
        return _Mapped(path, _stamp(path), view.shape, view.dtype)

    def _remember(self, key: tuple[str, int], view: np.ndarray) -> None:
        """Keep ``view`` among the open mappings, letting the oldest go beyond :data:`MAX_OPEN_MAPS`
        or :data:`MAX_OPEN_MAP_BYTES` (the newest always stays)."""
        view.flags.writeable = False
        self._open_maps[key] = view
        self._open_map_bytes += view.nbytes
        while len(self._open_maps) > 1 and (len(self._open_maps) > MAX_OPEN_MAPS
                                            or self._open_map_bytes > MAX_OPEN_MAP_BYTES):
            self._open_map_bytes -= self._open_maps.popitem(last=False)[1].nbytes

    def _mapping(self, key: tuple[str, int], kept: _Mapped) -> np.ndarray:
        """The open mapping of a kept frame, mapped again (not read) if it was let go.

        Raises
        ------
        RecordingError
            The file changed or went away since it was read and checked (the frame is named).
        """
        view = self._open_maps.get(key)
        if view is not None:
            self._open_maps.move_to_end(key)
            return view
        what = f"{self._name(key[1])}: {kept.path}"
        try:
            if _stamp(kept.path) != kept.stamp:
                raise RecordingError(f"{what} changed on disk after it was read; open the recording again")
            view = np.asarray(np.load(kept.path, mmap_mode="r", allow_pickle=False))
        except (OSError, ValueError) as err:
            raise RecordingError(f"{what}: cannot map it again ({err}); open the recording again") from None
        if view.shape != kept.shape or view.dtype != kept.dtype:
            raise RecordingError(f"{what} changed on disk after it was read; open the recording again")
        self._remember(key, view)
        return view

    def measurement(self, i: int) -> np.ndarray:
        """Frame ``i``'s measurement, ``R × S × C`` raw DN (black level not removed), read-only.

        As stored (uint16, uint8 or float32), except for a tone-mapped frame
        (:meth:`tone_mapped`) of a profile declaring ``sensor.tone_curve``: its curve is undone
        and the result is float32 linear DN. Read and checked on the first call, the same
        array on every later one.

        Raises
        ------
        RecordingError
            When the file is unreadable, not numeric, of the wrong shape or channel count,
            or holds NaN, Inf or negative values (the frame is named), or a frame marked
            ``tone_mapped: true`` has no ``sensor.tone_curve`` to undo.
        """
        arr = self._frame_array(("measurement", i), self._read_measurement)
        assert arr is not None
        return arr

    def _read_measurement(self, i: int) -> tuple[np.ndarray, Path]:
        """Frame ``i``'s measurement read and checked (:meth:`measurement`)."""
        fr = self.frames[i]
        rel = fr.measurement
        path = self._inside(rel, f"frame {i} 'measurement'")
        sensor = self.profile.sensor
        try:
            video = int(fr.extra[VIDEO_FRAME_FIELD]) if path.suffix.lower() in _VIDEO_SUFFIXES else None
            arr = read_frame_file(path, is_scene=False, video_frame=video, gray=len(sensor.channels) == 1,
                                  mmap=self._map(path))
        except RecordingError as err:
            raise RecordingError(f"{self._name(i)}: {err}") from None
        exp = (sensor.rows, sensor.cols)
        n_ch = len(sensor.channels)
        if arr.ndim not in (2, 3) or arr.shape[:2] != exp:
            raise RecordingError(
                f"{self._name(i)}: {rel}: shape {arr.shape} does not match the profile's "
                f"sensor {exp[0]}×{exp[1]}"
            )
        channels = arr.shape[2] if arr.ndim == 3 else 1
        if channels != n_ch:
            raise RecordingError(
                f"{self._name(i)}: {rel}: {channels} channel(s), the profile's sensor has {n_ch} "
                f"({', '.join(sensor.channels)})"
            )
        _check_values(arr, f"{self._name(i)}: {rel}", low=0.0, high=None)
        if self.tone_mapped(i):
            arr = self._linearize(i, arr)
        return arr, path

    def _linearize(self, i: int, arr: np.ndarray) -> np.ndarray:
        """Undo the profile's tone curve on frame ``i``'s stored values."""
        from thintact_sdk.pixels.tone_curve import linearize

        if self.profile.sensor.tone_curve is None:
            if self.frames[i].extra.get(TONE_MAPPED_FIELD) is True:
                raise RecordingError(
                    f"{self._name(i)}: marked '{TONE_MAPPED_FIELD}: true' but profile "
                    f"{self.profile.name!r} declares no sensor.tone_curve to undo")
            return arr  # a JPEG of a camera declared linear: read as stored
        try:
            out = linearize(arr, self.profile, f"{self._name(i)}: {self.frames[i].measurement}")
        except (ValueError, ProfileError) as err:
            raise RecordingError(str(err)) from None
        _check_values(out, f"{self._name(i)}: {self.frames[i].measurement} (linearised)", low=0.0, high=None)
        return out

    def scene(self, i: int) -> np.ndarray | None:
        """Frame ``i``'s scene, ``N × M × C`` float32 in [0, 1] (read-only), or None for unknown
        scenes. Read and checked on the first call, the same array on every later one.

        Raises
        ------
        RecordingError
            When the file is unreadable, not numeric, of the wrong shape, or holds values
            outside [0, 1] (NaN and Inf included); the frame is named.
        """
        return self._frame_array(("scene", i), self._read_scene)

    def _read_scene(self, i: int) -> tuple[np.ndarray, Path] | None:
        """Frame ``i``'s scene read and checked (:meth:`scene`)."""
        s = self.frames[i].scene
        if s is None:
            return None
        path = self._inside(s, f"frame {i} 'scene'")
        try:
            arr = read_frame_file(path, is_scene=True, mmap=self._map(path))
        except RecordingError as err:
            raise RecordingError(f"{self._name(i)}: {err}") from None
        exp = (self.profile.scene.rows, self.profile.scene.cols)
        n_ch = len(self.profile.sensor.channels)
        channels = arr.shape[2] if arr.ndim == 3 else 1
        allowed = sorted({1, 3, n_ch})  # an LCD shows RGB scenes to a monochrome sensor too
        if arr.ndim not in (2, 3) or arr.shape[:2] != exp or channels not in allowed:
            raise RecordingError(
                f"{self._name(i)}: {s}: shape {arr.shape} does not match the profile's scene "
                f"{exp[0]}×{exp[1]} with {' or '.join(map(str, allowed))} channel(s)"
            )
        _check_values(arr, f"{self._name(i)}: {s}", low=0.0, high=1.0 + SCENE_TOLERANCE)
        return arr, path

    def check_frames(self) -> None:
        """Read and check every frame (kept for the stages that follow), so that a bad one is
        refused before any output is written."""
        for i in range(len(self)):
            self.scene(i)
            self.measurement(i)

    def __iter__(self) -> Iterator[tuple[RecordingFrame, np.ndarray | None, np.ndarray]]:
        for i, fr in enumerate(self.frames):
            yield fr, self.scene(i), self.measurement(i)


def _is_number(value: object) -> bool:
    """A JSON number (not bool) that is finite."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _check_values(arr: np.ndarray, what: str, low: float, high: float | None) -> None:
    """Refuse NaN/Inf and values outside ``[low, high]`` (counts given in the message)."""
    if arr.dtype.kind == "f":
        bad = ~np.isfinite(arr)
        if bad.any():
            raise RecordingError(f"{what}: {int(bad.sum())} NaN/Inf value(s) (first at index "
                                 f"{tuple(int(v) for v in np.argwhere(bad)[0])}); refused")
    if arr.size == 0:
        raise RecordingError(f"{what}: empty array")
    lo, hi = float(arr.min()), float(arr.max())
    if lo < low:
        raise RecordingError(f"{what}: negative value {lo:g}; refused")
    if high is not None and hi > high:
        raise RecordingError(f"{what}: value {hi:g} above {high:g}; scenes are display values in [0, 1]")


def remove_partial_writes(root: Path) -> None:
    """Delete the temp files of atomic writes that a killed writer left (never complete files)."""
    for sub in (root, root / "scenes", root / "measurements"):
        if sub.is_dir():
            for tmp in sub.glob(".*.tmp"):
                tmp.unlink(missing_ok=True)


class RecordingWriter:
    """Writes a ``thintact-recording/1`` directory frame by frame, atomically.

    Opening an existing recording appends to it (resume): frames already in its manifest
    are kept and :meth:`has_label` tells a resuming writer what is already done. The
    existing recording must have been made with the same device physics and grids
    (:meth:`Profile.content_hash`), else a :class:`RecordingError` names both profiles.
    """

    def __init__(self, root: str | os.PathLike[str], profile: Profile) -> None:
        self.root = Path(root)
        self.profile = profile
        self.frames: list[RecordingFrame] = []
        mpath = self.root / "manifest.json"
        if mpath.is_file():
            existing = check_appendable(self.root, profile)
            self.frames = list(existing.frames)
            remove_partial_writes(self.root)
        self.root.mkdir(parents=True, exist_ok=True)
        (self.root / "scenes").mkdir(exist_ok=True)
        (self.root / "measurements").mkdir(exist_ok=True)
        ppath = self.root / "profile.json"
        if not ppath.is_file():  # self-contained: a tone-curve table file is inlined
            text = json.dumps(inline_table(profile).contract_dict(), indent=1) + "\n"
            atomic_write_bytes(ppath, text.encode("utf-8"))
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
        file_format: Literal["npy", "png", "jpg"] = "npy",
        jpeg_quality: int = 95,
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
        file_format
            ``npy`` (uint16 or float32), ``png`` (uint8 or uint16, lossless) or ``jpg`` (uint8,
            a camera's encoded output; read back as tone-mapped, see the module docstring).
        jpeg_quality
            JPEG quality 1-100 with ``file_format="jpg"``.
        extra
            JSON-serialisable per-frame metadata (timestamp_ns, frame_id, exposure_us, ...).
        """
        idx = len(self.frames)
        what = f"frame {idx} ({label})" if label else f"frame {idx}"
        if measurement.dtype.kind not in _NUMERIC_KINDS:
            raise RecordingError(f"{what}: measurement dtype {measurement.dtype} is not numeric")
        _check_values(measurement, f"{what}: measurement", low=0.0, high=None)
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in (label or f"frame{idx}"))
        stem = f"{idx:03d}_{safe}" if idx < 1000 else f"{idx:06d}_{safe}"
        if file_format == "npy":
            mrel = f"measurements/{stem}.npy"
            if measurement.dtype not in (np.uint16, np.float32):
                measurement = measurement.astype(np.float32)
            atomic_save_npy(self.root / mrel, measurement)
        else:
            mrel = f"measurements/{stem}.{file_format}"
            atomic_write_bytes(self.root / mrel, _encode_image(measurement, file_format, jpeg_quality, what))
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


def _encode_image(img: np.ndarray, file_format: str, quality: int, what: str) -> bytes:
    """``R × S × C`` (C 1 or 3, RGB) as PNG/JPEG bytes; JPEG needs uint8, PNG uint8/uint16."""
    import cv2

    allowed = (np.uint8,) if file_format == "jpg" else (np.uint8, np.uint16)
    if img.dtype not in allowed:
        raise RecordingError(f"{what}: a {file_format} measurement must be "
                             f"{' or '.join(np.dtype(a).name for a in allowed)}, got {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim == 3 and img.shape[2] != 3:
        raise RecordingError(f"{what}: {file_format} holds 1 or 3 channels, got {img.shape[2]}")
    bgr = img[..., ::-1] if img.ndim == 3 else img
    params = [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)] if file_format == "jpg" else []
    ok, buf = cv2.imencode(f".{file_format}", np.ascontiguousarray(bgr), params)
    if not ok:
        raise RecordingError(f"{what}: cannot encode the measurement as {file_format}")
    return bytes(buf.tobytes())


def check_appendable(root: str | os.PathLike[str], profile: Profile) -> Recording:
    """The existing recording at ``root``, after checking that frames of ``profile`` may be
    appended to it (same device physics and grids); raises RecordingError naming both."""
    existing = Recording(root, allow_empty=True)
    _check_same_device(existing.profile, profile, Path(root))
    return existing


def _check_same_device(existing: Profile, new: Profile, root: Path) -> None:
    """Refuse appending frames of another device (other grids or physics) to a recording."""
    if inline_table(existing).content_hash() == inline_table(new).content_hash():
        return

    def describe(p: Profile) -> str:
        return (f"{p.name!r} (sensor {p.sensor.rows}×{p.sensor.cols}×{len(p.sensor.channels)}, "
                f"scene {p.scene.rows}×{p.scene.cols})")

    raise RecordingError(
        f"{root} was recorded with profile {describe(existing)}; appending frames of profile "
        f"{describe(new)} would mix devices (their sensor, scene, mask, geometry, noise or physics "
        "fields differ); record into a new directory"
    )
