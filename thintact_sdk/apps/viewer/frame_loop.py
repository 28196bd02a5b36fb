"""The viewer's frame loop: reads a sensor on a thread and keeps the newest dashboard.

The loop reads a raw frame, turns it into a tactile frame (:meth:`Sensor.process`),
renders the dashboard (:mod:`thintact_sdk.apps.viewer.panels`) and publishes it as JPEG. Web
clients wait for the next published frame (:meth:`LiveView.wait_frame`) and report when
they have sent it (:meth:`LiveView.note_served`), which gives the served rate and the
latency from the camera timestamp to the frame leaving the server.

The record and snapshot buttons act here: :meth:`LiveView.snapshot` writes the newest
tactile frame, :meth:`LiveView.start_recording` makes the loop append every raw frame it
reads to a recording until :meth:`LiveView.stop_recording` (:mod:`thintact_sdk.apps.viewer.snapshots`).
"""

from __future__ import annotations

import statistics
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from thintact_sdk.apps.viewer.panels import Rates, encode_jpeg, render_dashboard
from thintact_sdk.apps.viewer.snapshots import DEFAULT_OUT, LiveRecorder, write_snapshot
from thintact_sdk.device.sensor import Sensor
from thintact_sdk.errors import EndOfStreamError, OutputError
from thintact_sdk.frames import TactileFrame

WINDOW = 30
"""Frames over which rates and median latencies are taken."""


@dataclass(frozen=True)
class Published:
    """One dashboard frame: JPEG bytes, sequence number and the tactile frame's facts."""

    seq: int
    jpeg: bytes
    camera_stamp_ns: int
    frame_id: int
    contact: bool


def _rate(stamps: deque[float]) -> float:
    if len(stamps) < 2 or stamps[-1] <= stamps[0]:
        return float("nan")
    return (len(stamps) - 1) / (stamps[-1] - stamps[0])


def _median(values: deque[float]) -> float:
    return statistics.median(values) if values else float("nan")


class LiveView:
    """Runs an opened :class:`~thintact_sdk.device.sensor.Sensor` and publishes its dashboard.

    Parameters
    ----------
    sensor
        An opened sensor (its first ``reference_frames`` frames are the no-contact
        reference: keep the membrane free when the viewer starts).
    title
        Shown under the panels (default: the profile's name).
    out
        Where snapshots and recordings go (default :data:`~thintact_sdk.apps.viewer.snapshots.DEFAULT_OUT`
        under the working directory); created on the first one.
    label
        The sensor's name in file names (default: the profile's name).
    """

    def __init__(self, sensor: Sensor, title: str | None = None, out: str | Path | None = None,
                 label: str | None = None) -> None:
        self.sensor = sensor
        self.title = title or f"thintact view {sensor.profile.name}"
        self.out = Path(out if out is not None else DEFAULT_OUT)
        self.label = label or sensor.profile.name
        self.error: str | None = None
        self._frame: TactileFrame | None = None
        self._recorder: LiveRecorder | None = None
        self._last_recording: LiveRecorder | None = None
        self._record_lock = threading.Lock()
        self._cond = threading.Condition()
        self._latest: Published | None = None
        self._stop = threading.Event()
        self._reset = threading.Event()
        self._thread: threading.Thread | None = None
        self._made: deque[float] = deque(maxlen=WINDOW)
        self._processing_ms: deque[float] = deque(maxlen=WINDOW)
        self._served: deque[float] = deque(maxlen=WINDOW)
        self._latency_ms: deque[float] = deque(maxlen=WINDOW)
        self._last_served_seq = -1
        self._lock = threading.Lock()

    # -- life cycle -------------------------------------------------------------------
    def start(self) -> LiveView:
        """Start the frame loop (returns at once)."""
        self._thread = threading.Thread(target=self._run, name="thintact-view", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the frame loop and wait for it; a running recording is closed."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        self.stop_recording()

    def reset_reference(self) -> None:
        """Make the next frames the no-contact reference (the membrane must be free)."""
        self._reset.set()

    # -- the loop ---------------------------------------------------------------------
    def _run(self) -> None:
        seq = 0
        try:
            while not self._stop.is_set():
                if self._reset.is_set():
                    self._reset.clear()
                    self.sensor.reset_reference()
                raw = self.sensor.read_raw()
                recorder = self._recorder
                if recorder is not None:
                    recorder.write(raw)
                frame = self.sensor.process(raw)
                self._frame = frame
                self._note_made(frame)
                image = render_dashboard(raw, frame, self.sensor.profile, self.rates(), self.title)
                published = Published(seq, encode_jpeg(image), frame.timestamp_ns,
                                      frame.frame_id, frame.contact)
                with self._cond:
                    self._latest = published
                    self._cond.notify_all()
                seq += 1
        except EndOfStreamError as err:
            self.error = f"the source ended: {err}"
        except Exception as err:  # noqa: BLE001 - shown on the page and printed by the CLI
            self.error = f"{type(err).__name__}: {err}"
        with self._cond:
            self._cond.notify_all()

    def _note_made(self, frame: TactileFrame) -> None:
        with self._lock:
            self._made.append(time.monotonic())
            if frame.latency_ms is not None:
                self._processing_ms.append(frame.latency_ms)

    # -- clients ----------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def latest(self) -> Published | None:
        """The newest published frame, or None before the first."""
        return self._latest

    def wait_frame(self, after_seq: int, timeout_s: float) -> Published | None:
        """The newest frame with ``seq > after_seq``, waiting up to ``timeout_s``.

        Returns the newest frame (even an old one) when the loop has stopped, and None
        when there is no frame at all.
        """
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._latest is None or self._latest.seq <= after_seq:
                left = deadline - time.monotonic()
                if left <= 0 or not self.running:
                    break
                self._cond.wait(min(left, 0.1))
            return self._latest

    def note_served(self, published: Published) -> None:
        """A client has been sent ``published`` (first send of each frame counts)."""
        now_ns = time.monotonic_ns()
        with self._lock:
            if published.seq <= self._last_served_seq:
                return
            self._last_served_seq = published.seq
            self._served.append(now_ns / 1e9)
            self._latency_ms.append((now_ns - published.camera_stamp_ns) / 1e6)

    # -- record and snapshot ------------------------------------------------------------
    def snapshot(self) -> list[Path]:
        """Write the newest tactile frame's reconstruction (PNG) and depth (``.npy``).

        Raises
        ------
        OutputError
            No frame yet, or the output directory cannot be written.
        """
        frame = self._frame
        if frame is None:
            raise OutputError("no frame yet to take a snapshot of")
        return write_snapshot(self.out, self.label, frame)

    def start_recording(self) -> Path:
        """Start appending every raw frame to a new recording; returns its directory.

        Raises
        ------
        OutputError
            A recording is already running, or the output directory cannot be written.
        """
        with self._record_lock:
            if self._recorder is not None and self._recorder.active:
                raise OutputError(f"already recording into {self._recorder.path}")
            self._recorder = LiveRecorder(self.out, self.label, self.sensor.profile)
            return self._recorder.path

    def stop_recording(self) -> tuple[Path, int] | None:
        """Stop the running recording; its directory and frame count, or None when none ran."""
        with self._record_lock:
            recorder, self._recorder = self._recorder, None
        if recorder is None:
            return None
        recorder.close()
        self._last_recording = recorder
        return recorder.path, recorder.frames

    def recording(self) -> dict[str, Any] | None:
        """The running (else the last) recording: path, frames, active, error; None if none."""
        recorder = self._recorder or self._last_recording
        if recorder is None:
            return None
        return {"path": str(recorder.path), "frames": recorder.frames, "active": recorder.active,
                "error": recorder.error}

    def rates(self) -> Rates:
        """Current rates and median latencies (over the last :data:`WINDOW` frames)."""
        with self._lock:
            return Rates(sensor_fps=_rate(self._made), served_fps=_rate(self._served),
                         latency_ms=_median(self._latency_ms),
                         processing_ms=_median(self._processing_ms))

    def stats(self) -> dict[str, Any]:
        """JSON-ready state for ``/stats.json``."""
        rates = self.rates()
        latest = self._latest

        def num(value: float) -> float | None:
            return round(value, 2) if value == value else None

        return {
            "profile": self.sensor.profile.name,
            "seq": latest.seq if latest else None,
            "frame_id": latest.frame_id if latest else None,
            "contact": latest.contact if latest else None,
            "sensor_fps": num(rates.sensor_fps),
            "served_fps": num(rates.served_fps),
            "latency_ms": num(rates.latency_ms),
            "processing_ms": num(rates.processing_ms),
            "error": self.error,
            "recording": self.recording(),
        }
