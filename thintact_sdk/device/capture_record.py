"""Record a profile's camera to disk: what ``thintact record`` runs.

:func:`record` writes a ``thintact-recording/1`` directory (CONTRACTS §3). Every frame goes
through :func:`thintact_sdk.device.cameras.to_measurement` (Bayer binning, profile black
level); measurements are stored as uint16 when every value is an integer in 0..65535, else
float32 (:func:`storage_array`). Each manifest entry carries ``timestamp_ns``, ``frame_id``,
``exposure_us`` (and ``gain_db``, ``device_timestamp_ns``, ``dropped_before`` when known). A
ground-truth scene that the camera reports (``meta["scene"]``, e.g. the virtual camera) is
saved as the frame's scene. ``keep_raw`` also keeps each raw mosaic (``raw/<index>.npy``, see
:mod:`thintact_sdk.formats.raw_frames`), which the ``replay`` camera then delivers as recorded.

:func:`record_log` writes an MCAP log instead
(:func:`thintact_sdk.formats.mcap.recorder.record_mcap`).

Both hold the output with :func:`~thintact_sdk.formats.output_lock.write_lock` while they
write, and decide under it whether the output may be written: of several runs racing for
the same output exactly one records. Dropped frames are counted in the returned
:class:`~thintact_sdk.device.capture_loop.RecordSummary` (``dropped``, ``gaps``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.device.cameras import create_camera, to_measurement
from thintact_sdk.device.capture_loop import RecordSummary, capture_frames
from thintact_sdk.errors import OutputError, RecordingError, ThinTactError
from thintact_sdk.formats.output_lock import write_lock
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.raw_frames import save_raw_frame
from thintact_sdk.formats.recording import RecordingWriter, check_appendable
from thintact_sdk.frames import RawFrame

__all__ = ["record", "record_log", "storage_array"]


def storage_array(data: np.ndarray) -> np.ndarray:
    """The measurement as stored: uint16 when integral and within 0..65535, else float32."""
    if data.size and np.all(np.isfinite(data)):
        lo, hi = float(data.min()), float(data.max())
        if lo >= 0 and hi <= 65535 and np.array_equal(data, np.round(data)):
            return data.astype(np.uint16)
    return data.astype(np.float32, copy=False)


def _frame_fields(raw: RawFrame, missing_before: int) -> dict[str, Any]:
    extra: dict[str, Any] = {"timestamp_ns": int(raw.timestamp_ns), "frame_id": int(raw.frame_id),
                             "exposure_us": raw.exposure_us}
    if raw.gain_db is not None:
        extra["gain_db"] = raw.gain_db
    if raw.device_timestamp_ns is not None:
        extra["device_timestamp_ns"] = int(raw.device_timestamp_ns)
    if missing_before:
        extra["dropped_before"] = missing_before
    return extra


def _scene_of(raw: RawFrame, profile: Profile) -> np.ndarray | None:
    scene = raw.meta.get("scene")
    if isinstance(scene, np.ndarray) and scene.shape[:2] == (profile.scene.rows, profile.scene.cols):
        return scene.astype(np.float32, copy=False)
    return None


def record(
    profile: Profile,
    frames: int,
    out: Path,
    *,
    keep_raw: bool = False,
    timeout_s: float = 5.0,
    settings: dict[str, Any] | None = None,
    append: bool = False,
    scenes: bool = True,
    progress: bool = True,
    buffer_mb: float = 512.0,
) -> RecordSummary:
    """Record ``frames`` frames from the profile's camera into the directory ``out``.

    A capture thread reads the camera into a queue of at most ``buffer_mb`` MiB of frames
    while this thread bins and writes them, so a burst faster than the disk is absorbed;
    when the queue is full the capture thread waits and the camera drops frames, which the
    frame-id gaps then report (:func:`thintact_sdk.device.capture_loop.capture_frames`).

    The directory is held with :func:`~thintact_sdk.formats.output_lock.write_lock` for the
    whole recording, and whether it already holds a recording is decided under that lock:
    of several runs racing for the same ``out`` exactly one records, the others fail.
    ``settings`` override the profile's camera settings; ``scenes`` saves the scenes the
    camera reports; ``progress`` draws a progress bar on stderr.

    Raises
    ------
    RecordingError
        When ``out`` already holds a recording and ``append`` is false, or holds one of
        another device.
    OutputError
        When another process is recording into ``out``.
    DeviceError
        When the camera fails; every frame written before the fault stays in the recording.
    """
    if frames <= 0:
        raise ThinTactError("--frames must be at least 1")
    with write_lock(out, "directory"):
        if (out / "manifest.json").is_file():
            if not append:
                raise RecordingError(f"{out} already holds a recording; choose a new --out or pass --append")
            check_appendable(out, profile)  # before the camera is opened
        save_raw = save_raw_frame if keep_raw else None
        camera = create_camera(profile, settings=settings)
        sink = _RecordingSink(out, profile, save_raw=save_raw, scenes=scenes)
        return capture_frames(camera, profile, frames, sink, saved_in=out, timeout_s=timeout_s,
                              buffer_mb=buffer_mb, progress=progress)


def record_log(
    profile: Profile,
    frames: int,
    out: Path,
    *,
    overwrite: bool = False,
    tactile: bool = True,
    timeout_s: float = 5.0,
    settings: dict[str, Any] | None = None,
    compression: str = "none",
    image_encoding: str = "rgb8",
    raw_preview: bool | None = None,
    progress: bool = True,
    buffer_mb: float = 512.0,
) -> RecordSummary:
    """Record ``frames`` camera frames into the MCAP file ``out`` (``record --format mcap``).

    The file is held with :func:`~thintact_sdk.formats.output_lock.write_lock` while it is
    written; an existing ``out`` is replaced only with ``overwrite`` (MCAP logs are never
    appended to). The other options are those of
    :func:`thintact_sdk.formats.mcap.recorder.record_mcap`: ``tactile`` adds each frame's
    reconstruction, depth, markers and contact; ``compression`` is ``none``, ``lz4`` or
    ``zstd``; ``image_encoding`` ``rgb8`` or ``32FC3``; ``raw_preview`` ``None`` writes the rgb8
    preview where the raw encoding needs it, ``False`` never.

    Raises
    ------
    OutputError
        When ``out`` exists and ``overwrite`` is false, or another process writes it.
    RecordingError, DeviceError
        As :func:`~thintact_sdk.formats.mcap.recorder.record_mcap`.
    """
    from thintact_sdk.formats.mcap.recorder import record_mcap

    with write_lock(out, "file"):  # exactly one of several runs racing for the same out
        if out.exists():
            if not overwrite:
                raise OutputError(f"--out {out} already exists; pass --force to overwrite it "
                                  "or choose another path")
            out.unlink()
        return record_mcap(profile, frames, out, tactile=tactile, timeout_s=timeout_s, settings=settings,
                           compression=compression, image_encoding=image_encoding,
                           raw_preview=raw_preview, progress=progress, buffer_mb=buffer_mb)


class _RecordingSink:
    """Bins each frame and appends it to a ``thintact-recording/1`` directory."""

    def __init__(self, out: Path, profile: Profile, *, save_raw: Any, scenes: bool) -> None:
        self.out = out
        self.profile = profile
        self.save_raw = save_raw
        self.scenes = scenes
        self._writer: RecordingWriter | None = None
        self._first_index = 0

    def start(self) -> None:
        self._writer = RecordingWriter(self.out, self.profile)
        self._first_index = len(self._writer.frames)

    def write(self, index: int, raw: RawFrame, dropped_before: int) -> None:
        assert self._writer is not None
        meas = to_measurement(raw, self.profile)
        extra = _frame_fields(raw, dropped_before)
        at = self._first_index + index
        if self.save_raw is not None:
            extra.update(self.save_raw(self.out, at, raw))
        self._writer.add(
            storage_array(meas.data),
            scene=_scene_of(raw, self.profile) if self.scenes else None,
            label=f"frame{at:06d}",
            **extra,
        )

    def close(self) -> None:
        """Nothing to finish: every frame is in the manifest as soon as it is added."""
