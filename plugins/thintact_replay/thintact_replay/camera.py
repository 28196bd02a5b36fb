"""``replay``: a camera that plays a ``thintact-recording/1`` directory.

Each recorded measurement (``R × S × 3`` raw DN) is delivered as a ``2R × 2S`` Bayer mosaic
built with :func:`thintact_sdk.pixels.bayer.mosaic_from_rgb` in the profile's CFA layout, so
:func:`thintact_sdk.device.cameras.to_measurement` gives the recorded measurement back exactly
(profile ``bayer_pattern: none`` delivers the ``R × S × 3`` frame itself; a monochrome
profile the ``R × S`` frame; an ``R, Gr, Gb, B`` profile the per-site mosaic). A profile with
``sensor.tone_curve`` gets the linear measurement re-encoded with the curve (float32), as the
camera delivered it, so that ``to_measurement`` undoes it once. Frames recorded
with ``--raw`` are delivered as the camera gave them, unless ``settings.raw`` is false.

Settings
--------
path
    The recording directory (relative paths are relative to the profile file). Required.
rate
    ``"recorded"`` (default): frames are delivered at their recorded times (``timestamp_ns``
    in the manifest; ``fps`` when the recording has none), divided by ``speed``.
    ``"fast"``: as fast as they are read.
speed
    Playback speed factor for ``rate: recorded`` (default 1.0).
fps
    Rate used when the recording holds no timestamps (default 0: as fast as possible).
loop
    Start again after the last frame (default false). Frame ids keep increasing.
raw
    Use kept raw mosaics when present (default true).
scenes
    Put each frame's ground-truth scene, when recorded, into ``meta["scene"]`` (default true).

End of recording
----------------
Without ``loop``, :meth:`ReplayCamera.read` raises :class:`EndOfRecording` (a
``thintact_sdk.errors.EndOfStreamError``) after the last frame; iterating over the camera
(``for raw in cam``) stops there instead.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field

from thintact_replay.pacing import wait_until_due
from thintact_sdk.errors import (
    DeviceError,
    EndOfStreamError,
    RecordingError,
)
from thintact_sdk.frames import RawFrame
from thintact_sdk.interfaces import Camera, CameraCapabilities
from thintact_sdk.plugin_support import (
    RAW_FIELD,
    CameraSettings,
    Profile,
    Recording,
    channel_layout,
    load_raw_data,
    mosaic_from_planes,
    mosaic_from_rgb,
    parse_camera_settings,
    read_npy,
)
from thintact_sdk.plugin_support import encode as encode_tone


class EndOfRecording(EndOfStreamError):
    """The replayed recording has no more frames (and ``loop`` is off)."""


def _check_frame_files(rec: Recording, scenes: bool) -> None:
    """Raise RecordingError naming the first frame with a missing or truncated file.

    Checks each frame's measurement, kept raw mosaic, and (with ``scenes``) its scene.
    """
    for i, fr in enumerate(rec.frames):
        names = [fr.measurement]
        raw = fr.extra.get(RAW_FIELD)
        if isinstance(raw, str):
            names.append(raw)
        if scenes and fr.scene is not None:
            names.append(fr.scene)
        for rel in names:
            path = rec.root / rel
            problem = None
            if not path.is_file():
                problem = "is missing"
            elif path.suffix.lower() == ".npy":
                try:  # header checked first (no objects, all declared data present), then mapped
                    read_npy(path, what="frame", error=RecordingError, kinds="uif", mmap=True)
                except RecordingError as err:
                    problem = f"is truncated, damaged or not a plain .npy array ({err})"
            if problem:
                raise RecordingError(
                    f"recording {rec.root} is damaged: frame {i} file {rel} {problem}; "
                    f"frames 0..{i - 1} are intact" if i else
                    f"recording {rec.root} is damaged: frame 0 file {rel} {problem}"
                )


class ReplaySourceSettings(CameraSettings):
    """``camera.settings`` every replay source takes (a recording directory or an MCAP log)."""

    path: str = Field(min_length=1, description="the recording directory or .mcap log to play")
    rate: Literal["recorded", "fast"] = "recorded"
    speed: float = Field(default=1.0, gt=0, le=1000)
    loop: bool = Field(default=False, strict=True)


class ReplayCameraSettings(ReplaySourceSettings):
    """``camera.settings`` of the replay camera on a recording directory (module docstring)."""

    fps: float = Field(default=0.0, ge=0, le=10_000)
    raw: bool = Field(default=True, strict=True)
    scenes: bool = Field(default=True, strict=True)


class ReplayCamera(Camera):
    """Plays a recording through the :class:`~thintact_sdk.interfaces.Camera` API."""

    name = "replay"

    def __init__(self, profile: Profile, settings: dict[str, Any]) -> None:
        parsed = parse_camera_settings(ReplayCameraSettings, settings, "replay")
        self.profile = profile
        self.path: Path = profile.resolve_path(parsed.path)
        self.rate = parsed.rate
        self.speed = parsed.speed
        self.fps = parsed.fps
        self.loop = parsed.loop
        self.use_raw = parsed.raw
        self.with_scenes = parsed.scenes
        self.pattern = profile.camera.bayer_pattern if profile.camera is not None else "RGGB"
        self._rec: Recording | None = None
        self._times_ns: list[int] = []
        self._ids: list[int] = []
        self._index = 0
        self._loops = 0
        self._t0 = 0.0
        self._is_open = False

    # -- lifecycle --------------------------------------------------------------------
    def open(self) -> None:
        """Open and check the recording: every frame's files present and complete."""
        rec = Recording(self.path, profile=self.profile)
        if len(rec) == 0:
            raise RecordingError(f"recording {self.path} has no frames")
        _check_frame_files(rec, self.with_scenes)
        self._rec = rec
        self._times_ns = self._schedule(rec)
        self._ids = [int(fr.extra.get("frame_id", i)) for i, fr in enumerate(rec.frames)]
        self._index = 0
        self._loops = 0
        self._t0 = time.monotonic()
        self._is_open = True

    def close(self) -> None:
        self._rec = None
        self._is_open = False

    def _schedule(self, rec: Recording) -> list[int]:
        """Delivery time of each frame after the first, ns (before ``speed``)."""
        stamps = [fr.extra.get("timestamp_ns") for fr in rec.frames]
        if all(isinstance(t, int) for t in stamps):
            t0 = int(stamps[0])  # type: ignore[arg-type]
            return [int(t) - t0 for t in stamps]  # type: ignore[arg-type]
        if self.fps > 0:
            return [int(round(i * 1e9 / self.fps)) for i in range(len(rec))]
        return [0] * len(rec)

    # -- Camera API ---------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._recording())

    def _recording(self) -> Recording:
        if self._rec is None:
            raise DeviceError("replay camera is not open; call open() or use it in a with block")
        return self._rec

    def capabilities(self) -> CameraCapabilities:
        rec = self._recording()
        raw, pixel_format = self._frame_data(0)
        fps = None
        if len(rec) > 1 and self._times_ns[-1] > 0:
            fps = (len(rec) - 1) * 1e9 / self._times_ns[-1]
        return CameraCapabilities(
            width=int(raw.shape[1]),
            height=int(raw.shape[0]),
            pixel_formats=[pixel_format],
            pixel_format=pixel_format,
            fps=fps,
            missing=["ExposureTime", "Gain"],
        )

    def _frame_data(self, i: int) -> tuple[np.ndarray, str]:
        rec = self._recording()
        fr = rec.frames[i]
        if self.use_raw and isinstance(fr.extra.get(RAW_FIELD), str):
            return load_raw_data(rec.root, fr.extra)
        meas = rec.measurement(i)  # linear DN (a tone-mapped frame's curve already undone)
        if meas.ndim == 2:
            meas = meas[..., None]
        layout = channel_layout(self.profile)
        want = len(self.profile.sensor.channels)
        if meas.shape[2] != want:
            raise RecordingError(
                f"{fr.measurement}: {meas.shape[2]} channels; replay needs the profile's {want} "
                f"({', '.join(self.profile.sensor.channels)})"
            )
        if self.profile.sensor.tone_curve is not None:
            # deliver what the camera delivered: to_measurement undoes the curve again
            meas = encode_tone(meas, self.profile).astype(np.float32)
        suffix = "16" if meas.dtype == np.uint16 else "8" if meas.dtype == np.uint8 else "32f"
        if layout == "mono":
            return np.ascontiguousarray(meas[..., 0]), f"Mono{suffix}"
        if self.pattern == "none" and layout == "binned":
            return np.ascontiguousarray(meas), f"RGB{suffix}"
        pattern = "RGGB" if self.pattern == "none" else self.pattern
        fmt = {"RGGB": "BayerRG", "BGGR": "BayerBG", "GRBG": "BayerGR", "GBRG": "BayerGB"}
        mosaic = mosaic_from_planes(meas, pattern) if layout == "planes" else mosaic_from_rgb(meas, pattern)
        return mosaic, f"{fmt[pattern]}{suffix}"

    def read(self, timeout_s: float = 2.0) -> RawFrame:
        """The next recorded frame, at its recorded time (``rate: recorded``) or at once.

        Raises
        ------
        EndOfRecording
            After the last frame when ``loop`` is off.
        DeviceTimeoutError
            When the next frame is due later than ``timeout_s`` from now.
        RecordingError
            When a frame's file cannot be read.
        """
        rec = self._recording()
        n = len(rec)
        if self._index >= n:
            if not self.loop:
                raise EndOfRecording(
                    f"recording {self.path} ended after {n} frames "
                    "(set camera.settings.loop: true to play it again)"
                )
            self._index = 0
            self._loops += 1
        i = self._index
        if self.rate == "recorded":
            period_ns = self._times_ns[-1] / (n - 1) if n > 1 else 0.0
            cycle_ns = self._times_ns[-1] + period_ns
            wait_until_due(self._t0, self._loops * cycle_ns + self._times_ns[i], self.speed,
                           timeout_s, f"frame {i}")
        data, pixel_format = self._frame_data(i)
        fr = rec.frames[i]
        span = self._ids[-1] - self._ids[0] + 1
        meta: dict[str, Any] = {"index": i, "loop": self._loops, "source": str(self.path)}
        if fr.label is not None:
            meta["label"] = fr.label
        if "timestamp_ns" in fr.extra:
            meta["recorded_timestamp_ns"] = fr.extra["timestamp_ns"]
        if self.with_scenes and fr.scene is not None:
            meta["scene"] = rec.scene(i)
        dev_ts = fr.extra.get("device_timestamp_ns")
        exposure = fr.extra.get("exposure_us")
        gain = fr.extra.get("gain_db")
        self._index += 1
        return RawFrame(
            data=data,
            timestamp_ns=time.monotonic_ns(),
            frame_id=self._ids[i] + self._loops * span,
            pixel_format=pixel_format,
            exposure_us=float(exposure) if exposure is not None else None,
            gain_db=float(gain) if gain is not None else None,
            device_timestamp_ns=int(dev_ts) if dev_ts is not None else None,
            meta=meta,
        )

    def __iter__(self) -> Iterator[RawFrame]:
        """Every remaining frame (forever with ``loop``); ends at the end of the recording."""
        while True:
            try:
                yield self.read(timeout_s=float("inf"))
            except EndOfRecording:
                return
