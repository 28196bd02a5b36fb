"""One capture loop for every writer of camera frames (``thintact record``, MCAP logs).

:func:`capture_frames` opens a camera, reads ``frames`` frames on a thread into a bounded
queue (:class:`BufferedReader`), reports open-time warnings, bit-depth problems and
dropped frames (gaps in the camera's frame ids), drives a progress bar, and hands each
frame to a :class:`FrameSink` that stores it. The sink decides the format; the loop
decides nothing about it. Camera faults keep every frame the sink already stored and say
how many there are.
"""

from __future__ import annotations

import queue
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from thintact_sdk.device.cameras import FrameGapCounter, bit_depth_problem
from thintact_sdk.errors import DeviceError, EndOfStreamError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.frames import RawFrame
from thintact_sdk.interfaces import Camera

MAX_GAP_NOTES = 10
"""Gaps reported one by one while capturing; later ones are only counted."""


@dataclass
class RecordSummary:
    """What a capture run did."""

    frames: int = 0
    dropped: int = 0
    gaps: list[tuple[int, int]] = field(default_factory=list)
    elapsed_s: float = 0.0
    camera_fps: float | None = None
    """Frame rate from the frames' own timestamps (first to last)."""
    ended_early: str | None = None


class FrameSink(Protocol):
    """Where :func:`capture_frames` puts the frames (a recording directory, an MCAP log)."""

    def start(self) -> None:
        """Called once the camera is open (create files only now)."""

    def write(self, index: int, raw: RawFrame, dropped_before: int) -> None:
        """Store frame number ``index`` (0-based in this run); ``dropped_before`` frames
        were missing just before it."""

    def close(self) -> None:
        """Called once at the end, also after a fault (flush, finish the file)."""


def capture_frames(
    camera: Camera,
    profile: Profile,
    frames: int,
    sink: FrameSink,
    *,
    saved_in: Path,
    timeout_s: float = 5.0,
    buffer_mb: float = 512.0,
    progress: bool = True,
) -> RecordSummary:
    """Read ``frames`` frames from ``camera`` (not yet open) into ``sink``.

    Parameters
    ----------
    camera
        The camera; it is opened here and always closed.
    profile
        The device profile (for the bit-depth check of the first frame).
    frames
        Frames to read (≥ 1); fewer when the source ends (``summary.ended_early``).
    sink
        Stores each frame.
    saved_in
        Where the frames go, named in the error when the camera fails.
    timeout_s
        Longest wait for one frame, s.
    buffer_mb
        Memory for frames read but not yet stored, MiB (at least two frames); when full,
        the reading thread waits and the camera drops frames, which the gaps then report.
    progress
        Show a progress bar with the live rate, queue and drop count.

    Raises
    ------
    DeviceError
        When the camera fails; every frame stored before the fault stays stored.
    """
    gaps = FrameGapCounter()
    summary = RecordSummary()
    stamps: list[int] = []
    t0 = time.monotonic()
    bar = CaptureProgress(frames, enabled=progress)
    reader: BufferedReader | None = None
    started = False
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            camera.open()
        opened_with = [str(w.message) for w in caught]
        for message in opened_with:
            CaptureProgress.warn(message)
        sink.start()  # only once the camera works
        started = True
        reader = BufferedReader(camera, frames, timeout_s, buffer_mb * 2**20)
        with bar:
            for i in range(frames):
                try:
                    raw = reader.next()
                except EndOfStreamError as err:
                    summary.ended_early = str(err)
                    break
                missing = gaps.update(raw.frame_id)
                if missing and len(gaps.gaps) <= MAX_GAP_NOTES:
                    bar.note(f"{missing} frame(s) dropped before frame id {raw.frame_id}"
                             + ("; further gaps are counted, not listed"
                                if len(gaps.gaps) == MAX_GAP_NOTES else ""))
                if i == 0:
                    depth_problem = bit_depth_problem(raw.pixel_format, profile)
                    if depth_problem and not any(depth_problem in m for m in opened_with):
                        bar.note(depth_problem)
                sink.write(i, raw, missing)
                stamps.append(raw.timestamp_ns)
                summary.frames += 1
                bar.advance(summary.frames, time.monotonic() - t0, gaps.dropped, reader.buffered)
    except DeviceError as err:
        raise type(err)(f"{err} ({summary.frames} frame(s) were saved in {saved_in})") from None
    finally:
        if reader is not None:
            reader.stop()
        camera.close()
        if started:
            sink.close()
    summary.elapsed_s = time.monotonic() - t0
    summary.dropped, summary.gaps = gaps.dropped, list(gaps.gaps)
    if len(stamps) > 1 and stamps[-1] > stamps[0]:
        summary.camera_fps = (len(stamps) - 1) * 1e9 / (stamps[-1] - stamps[0])
    return summary


class BufferedReader:
    """Reads ``frames`` frames from an opened camera on a thread into a bounded queue.

    The queue holds at most ``buffer_bytes`` of frame data (at least two frames); camera
    errors travel through the queue and are raised by :meth:`next` in order.
    """

    def __init__(self, camera: Any, frames: int, timeout_s: float, buffer_bytes: float) -> None:
        self.camera = camera
        self.frames = frames
        self.timeout_s = timeout_s
        self.buffer_bytes = buffer_bytes
        self._queue: queue.Queue[tuple[RawFrame | None, BaseException | None]] | None = None
        self._ready = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="record-capture", daemon=True)
        self._first: tuple[RawFrame | None, BaseException | None] | None = None
        self._thread.start()

    @property
    def buffered(self) -> int:
        """Frames read from the camera and not yet taken by :meth:`next`."""
        return self._queue.qsize() if self._queue is not None else 0

    def _put(self, item: tuple[RawFrame | None, BaseException | None]) -> bool:
        assert self._queue is not None
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        try:
            first = self.camera.read(timeout_s=self.timeout_s)
        except BaseException as err:  # noqa: BLE001 - handed to the consumer
            self._first = (None, err)
            self._ready.set()
            return
        slots = max(2, int(self.buffer_bytes // max(first.data.nbytes, 1)))
        self._queue = queue.Queue(maxsize=slots)
        self._first = (first, None)
        self._ready.set()
        for _ in range(self.frames - 1):
            if self._stop.is_set():
                return
            try:
                item: tuple[RawFrame | None, BaseException | None] = (
                    self.camera.read(timeout_s=self.timeout_s), None)
            except BaseException as err:  # noqa: BLE001
                item = (None, err)
            if not self._put(item) or item[1] is not None:
                return

    def next(self) -> RawFrame:
        """The next frame, or the camera's error in its place."""
        if self._first is None or not self._ready.is_set():
            while not self._ready.wait(0.1):
                if not self._thread.is_alive() and not self._ready.is_set():
                    raise DeviceError("the capture thread ended without a frame")
        if self._first is not None:
            item, self._first = self._first, None
        else:
            assert self._queue is not None
            while True:
                try:
                    item = self._queue.get(timeout=0.1)
                    break
                except queue.Empty:
                    if not self._thread.is_alive() and self._queue.empty():
                        raise DeviceError("the capture thread ended early") from None
        raw, err = item
        if err is not None:
            raise err
        assert raw is not None
        return raw

    def stop(self) -> None:
        """Stop reading and wait for the thread (bounded by the read timeout)."""
        self._stop.set()
        self._thread.join(timeout=self.timeout_s + 1.0)


class CaptureProgress:
    """A rich progress bar with a live fps and drop count (or nothing when disabled)."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.total = total
        self.enabled = enabled
        self._progress: Any = None
        self._task: Any = None

    def __enter__(self) -> CaptureProgress:
        if self.enabled:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

            self._progress = Progress(
                TextColumn("recording"), BarColumn(), MofNCompleteColumn(),
                TextColumn("{task.fields[fps]:.1f} fps"), TextColumn("{task.fields[queued]}"),
                TextColumn("{task.fields[drops]}"),
                transient=False,
            )
            self._progress.__enter__()
            self._task = self._progress.add_task("record", total=self.total, fps=0.0, drops="",
                                                queued="")
        return self

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.__exit__(None, None, None)

    def advance(self, done: int, elapsed_s: float, dropped: int, queued: int) -> None:
        """Show ``done`` frames after ``elapsed_s`` s, the drop count and the queue length."""
        if self._progress is not None:
            fps = done / elapsed_s if elapsed_s > 0 else 0.0
            self._progress.update(self._task, completed=done, fps=fps,
                                  drops=f"{dropped} dropped" if dropped else "",
                                  queued=f"{queued} queued" if queued else "")

    @staticmethod
    def warn(message: str) -> None:
        """One warning line on stderr (camera setting and bit-depth warnings at open)."""
        print(f"warning: {message}", file=sys.stderr)

    def note(self, message: str) -> None:
        """A warning line printed above the bar (or on stderr without one)."""
        if self._progress is not None:
            self._progress.console.print(f"[yellow]warning:[/yellow] {message}")
        else:
            print(f"warning: {message}", file=sys.stderr)
