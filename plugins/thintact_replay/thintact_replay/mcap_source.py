"""``replay`` of an MCAP log: ``camera.settings.path`` ending in ``.mcap``.

Plays the ``/thintact/raw`` frames of a log written by ``thintact record --format mcap``
(:mod:`thintact_sdk.formats.mcap`) exactly as the camera delivered them (same pixel format,
frame ids, data), at their recorded times or as fast as possible, like a
``thintact-recording/1`` directory. A log cut short by a killed writer or a full disk
plays up to its last complete chunk (with a warning).

Settings: ``path``, ``rate`` (``recorded`` | ``fast``), ``speed``, ``loop`` as for
recordings (:mod:`thintact_replay.camera`). The frames' ``meta`` holds ``index``,
``loop``, ``source`` and ``recorded_timestamp_ns``.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from thintact_replay.camera import EndOfRecording, ReplaySourceSettings
from thintact_replay.pacing import wait_until_due
from thintact_sdk.errors import DeviceError, RecordingError
from thintact_sdk.frames import RawFrame
from thintact_sdk.interfaces import Camera, CameraCapabilities
from thintact_sdk.plugin_support import McapLog, Profile, parse_camera_settings

MCAP_SUFFIX = ".mcap"


def is_mcap_path(path: object) -> bool:
    """True when a replay ``path`` setting names an MCAP log."""
    return isinstance(path, str | Path) and Path(str(path)).suffix.lower() == MCAP_SUFFIX


class McapReplayCamera(Camera):
    """Plays an MCAP log's raw frames through the :class:`~thintact_sdk.interfaces.Camera` API."""

    name = "replay"

    def __init__(self, profile: Profile, settings: dict[str, Any]) -> None:
        parsed = parse_camera_settings(ReplaySourceSettings, settings, "replay (MCAP log)")
        self.profile = profile
        self.path: Path = profile.resolve_path(parsed.path)
        self.rate = parsed.rate
        self.speed = parsed.speed
        self.loop = parsed.loop
        self._log: McapLog | None = None
        self._frames: Iterator[RawFrame] | None = None
        self._pending: RawFrame | None = None
        self._index = 0
        self._loops = 0
        self._first_stamp = 0
        self._first_id = 0
        self._cycle_ns = 0
        self._id_span = 0
        self._last: RawFrame | None = None
        self._t0 = 0.0

    # -- lifecycle --------------------------------------------------------------------
    def open(self) -> None:
        """Open the log and read its first raw frame (RecordingError when it has none)."""
        log = McapLog(self.path, recover=True)
        if log.torn is not None:
            warnings.warn(f"{self.path} was not closed properly; playing it up to its last "
                          f"complete chunk ({log.torn})", stacklevel=2)
        self._log = log
        self._frames = log.raw_frames()
        first = next(self._frames, None)
        if first is None:
            raise RecordingError(f"MCAP log {self.path} holds no /thintact/raw frames")
        self._pending, self._first_stamp, self._first_id = first, first.timestamp_ns, first.frame_id
        self._index = self._loops = 0
        self._cycle_ns = self._id_span = 0
        self._t0 = time.monotonic()

    def close(self) -> None:
        if self._frames is not None:
            getattr(self._frames, "close", lambda: None)()
        self._log = self._frames = self._pending = None

    def capabilities(self) -> CameraCapabilities:
        frame = self._peek()
        return CameraCapabilities(
            width=int(frame.data.shape[1]), height=int(frame.data.shape[0]),
            pixel_formats=[frame.pixel_format], pixel_format=frame.pixel_format,
            missing=["ExposureTime", "Gain"],
        )

    # -- frames -----------------------------------------------------------------------
    def _peek(self) -> RawFrame:
        if self._log is None or self._frames is None:
            raise DeviceError("replay camera is not open; call open() or use it in a with block")
        if self._pending is None:
            self._pending = next(self._frames, None)
            if self._pending is None:
                self._end_of_pass()
        assert self._pending is not None
        return self._pending

    def _end_of_pass(self) -> None:
        """After the last frame: stop, or start the next pass of a looping replay."""
        assert self._log is not None and self._last is not None
        if not self.loop:
            raise EndOfRecording(f"MCAP log {self.path} ended after {self._index} frames "
                                 "(set camera.settings.loop: true to play it again)")
        if self._loops == 0:
            span_ns = self._last.timestamp_ns - self._first_stamp
            n = max(self._index, 1)
            self._cycle_ns = span_ns + (span_ns // (n - 1) if n > 1 else 0)
            self._id_span = self._last.frame_id - self._first_id + 1
        self._loops += 1
        self._index = 0
        self._frames = self._log.raw_frames()
        self._pending = next(self._frames, None)

    def read(self, timeout_s: float = 2.0) -> RawFrame:
        """The next logged frame, at its recorded time (``rate: recorded``) or at once.

        Raises
        ------
        EndOfRecording
            After the last frame when ``loop`` is off.
        DeviceTimeoutError
            When the next frame is due later than ``timeout_s`` from now.
        """
        frame = self._peek()
        if self.rate == "recorded":
            offset_ns = self._loops * self._cycle_ns + frame.timestamp_ns - self._first_stamp
            wait_until_due(self._t0, offset_ns, self.speed, timeout_s,
                           f"frame {self._index} of {self.path}")
        self._pending, self._last = None, frame
        meta = {"index": self._index, "loop": self._loops, "source": str(self.path),
                "recorded_timestamp_ns": frame.timestamp_ns}
        self._index += 1
        return RawFrame(data=frame.data, timestamp_ns=time.monotonic_ns(),
                        frame_id=frame.frame_id + self._loops * self._id_span,
                        pixel_format=frame.pixel_format, meta=meta)
