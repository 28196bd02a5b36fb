"""``thintact record``: capture N frames from a profile's camera into a recording.

The recording is a ``thintact-recording/1`` directory (CONTRACTS §3). Every frame goes
through :func:`thintact_sdk.capture.to_measurement` (Bayer binning, profile black level);
measurements are stored as uint16 when every value is an integer in 0..65535, else float32.
Each manifest entry carries ``timestamp_ns``, ``frame_id``, ``exposure_us`` (and
``gain_db``, ``device_timestamp_ns``, ``dropped_before`` when known). A ground-truth scene
that the camera reports (``meta["scene"]``, e.g. the virtual camera) is saved as the
frame's scene. ``--raw`` also keeps each raw mosaic (``raw/<index>.npy``, see
:mod:`thintact_replay.rawframes`), which the ``replay`` camera then delivers as recorded.

Dropped frames (gaps in the camera's frame ids) are never silent: each gap is reported,
the count is printed at the end, and ``--fail-on-drop`` turns any drop into an error.
"""

from __future__ import annotations

import argparse
import queue
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from thintact_sdk.capture import (
    FrameGapCounter,
    bit_depth_problem,
    create_camera,
    to_measurement,
)
from thintact_sdk.cli.argtypes import positive_float, positive_int
from thintact_sdk.cli.output_path import add_force_argument, claim_output
from thintact_sdk.errors import DeviceError, EndOfStreamError, RecordingError, ThinTactError
from thintact_sdk.frames import RawFrame
from thintact_sdk.profile import Profile, load_profile
from thintact_sdk.recording import RecordingWriter, check_appendable

CLI_DESCRIPTION = """\
Capture N frames from the profile's camera into a thintact-recording/1 directory.

Frames are binned with the profile's Bayer layout; measurements keep the black level and
are stored as uint16 when integral, else float32. Each frame records timestamp_ns,
frame_id and exposure_us (and gain_db, device_timestamp_ns, dropped_before when known);
a ground-truth scene reported by the camera (the virtual camera) is saved with it.
--raw also keeps the raw mosaics (raw/*.npy), which the replay camera delivers as recorded.

Dropped frames (gaps in the camera's frame ids) are never silent: gaps are reported as they
happen, the total at the end, and --fail-on-drop makes any drop an error (exit status 2).

--format mcap writes an MCAP log (--out FILE.mcap) with ROS 2 message encodings instead:
the raw frames and, unless --no-tactile, each frame's reconstruction, depth, markers and
contact (topics, types and how to open it: docs/logging.md).
"""

MAX_GAP_NOTES = 10
"""Gaps reported one by one while recording; later ones are only counted."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "record",
        help="record frames from a profile's camera into a thintact-recording/1 directory",
        description=CLI_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--profile", required=True, help="profile name or file")
    p.add_argument("--frames", type=positive_int, required=True, metavar="N",
                   help="frames to record (>= 1)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="recording directory (or .mcap file with --format mcap) to create")
    p.add_argument("--raw", action="store_true", help="also keep the raw mosaics (raw/*.npy)")
    p.add_argument("--timeout", type=positive_float, default=5.0, metavar="S",
                   help="longest wait for one frame in seconds (default 5)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a camera setting (YAML value), e.g. --set fps=0")
    p.add_argument("--append", action="store_true",
                   help="add frames to an existing recording of the same device (resume)")
    p.add_argument("--fail-on-drop", action="store_true",
                   help="exit with an error if the camera dropped any frame")
    p.add_argument("--no-scenes", action="store_true",
                   help="do not save ground-truth scenes reported by the camera")
    p.add_argument("--buffer-mb", type=positive_float, default=512.0, metavar="MB",
                   help="memory for frames waiting to be written (default 512)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    mcap = p.add_argument_group("MCAP logs (--format mcap, docs/logging.md)")
    mcap.add_argument("--format", choices=("recording", "mcap"), default="recording",
                      help="thintact-recording/1 directory (default) or an MCAP file")
    mcap.add_argument("--no-tactile", action="store_true",
                      help="MCAP: raw frames only (no reconstruction, depth, markers, contact)")
    mcap.add_argument("--compression", choices=("none", "lz4", "zstd"), default="none",
                      help="MCAP chunk compression (default none: raw frames barely compress)")
    mcap.add_argument("--image-encoding", choices=("rgb8", "32FC3"), default="rgb8",
                      help="MCAP reconstruction encoding (default rgb8; 32FC3 is exact)")
    add_force_argument(p, "a new recording into an existing non-empty directory that is not "
                       "a recording (an existing recording needs --append)")
    p.set_defaults(func=run)


@dataclass
class RecordSummary:
    """What a recording run did."""

    frames: int = 0
    dropped: int = 0
    gaps: list[tuple[int, int]] = field(default_factory=list)
    elapsed_s: float = 0.0
    camera_fps: float | None = None
    """Frame rate from the frames' own timestamps (first to last)."""
    ended_early: str | None = None


def parse_settings(pairs: list[str]) -> dict[str, Any]:
    """``["key=value", ...]`` → dict with YAML-typed values."""
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ThinTactError(f"--set needs KEY=VALUE, got {pair!r}")
        out[key.strip()] = yaml.safe_load(value)
    return out


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
    """Record ``frames`` frames from the profile's camera into ``out``.

    A capture thread reads the camera into a queue of at most ``buffer_mb`` MiB of frames
    while this thread bins and writes them, so a burst faster than the disk is absorbed;
    when the queue is full the capture thread waits and the camera drops frames, which the
    frame-id gaps then report.

    Raises
    ------
    RecordingError
        When ``out`` already holds a recording and ``append`` is false.
    DeviceError
        When the camera fails; every frame written before the fault stays in the recording.
    """
    if frames <= 0:
        raise ThinTactError("--frames must be at least 1")
    if (out / "manifest.json").is_file():
        if not append:
            raise RecordingError(f"{out} already holds a recording; choose a new --out or pass --append")
        check_appendable(out, profile)  # before the camera is opened
    save_raw = None
    if keep_raw:
        try:
            from thintact_replay.rawframes import save_raw_frame
        except ImportError:
            raise ThinTactError("--raw needs the thintact-replay plugin (plugins/thintact_replay)") from None
        save_raw = save_raw_frame
    camera = create_camera(profile, settings=settings)
    gaps = FrameGapCounter()
    summary = RecordSummary()
    stamps: list[int] = []
    t0 = time.monotonic()
    bar = _Progress(frames, enabled=progress)
    reader: _BufferedReader | None = None
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            camera.open()
        opened_with = [str(w.message) for w in caught]
        for message in opened_with:
            _Progress.warn(message)
        writer = RecordingWriter(out, profile)  # only once the camera works
        first_index = len(writer.frames)
        reader = _BufferedReader(camera, frames, timeout_s, buffer_mb * 2**20)
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
                meas = to_measurement(raw, profile)
                extra = _frame_fields(raw, missing)
                index = first_index + i
                if save_raw is not None:
                    extra.update(save_raw(out, index, raw))
                writer.add(
                    storage_array(meas.data),
                    scene=_scene_of(raw, profile) if scenes else None,
                    label=f"frame{index:06d}",
                    **extra,
                )
                stamps.append(raw.timestamp_ns)
                summary.frames += 1
                bar.advance(summary.frames, time.monotonic() - t0, gaps.dropped, reader.buffered)
    except DeviceError as err:
        raise type(err)(f"{err} ({summary.frames} frame(s) were saved in {out})") from None
    finally:
        if reader is not None:
            reader.stop()
        camera.close()
    summary.elapsed_s = time.monotonic() - t0
    summary.dropped, summary.gaps = gaps.dropped, list(gaps.gaps)
    if len(stamps) > 1 and stamps[-1] > stamps[0]:
        summary.camera_fps = (len(stamps) - 1) * 1e9 / (stamps[-1] - stamps[0])
    return summary


class _BufferedReader:
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


class _Progress:
    """A rich progress bar with a live fps and drop count (or nothing when disabled)."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.total = total
        self.enabled = enabled
        self._progress: Any = None
        self._task: Any = None

    def __enter__(self) -> _Progress:
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
        if self._progress is not None:
            self._progress.console.print(f"[yellow]warning:[/yellow] {message}")
        else:
            print(f"warning: {message}", file=sys.stderr)


def _record_mcap(args: argparse.Namespace, profile: Profile, out: Path) -> RecordSummary:
    """``--format mcap``: the options that only make sense for a recording directory fail."""
    from thintact_sdk.mcaplog.capture import record_mcap

    for flag, given in (("--raw", args.raw), ("--append", args.append),
                        ("--no-scenes", args.no_scenes)):
        if given:
            raise ThinTactError(f"{flag} applies to --format recording only; an MCAP log "
                                "always holds the raw frames and is never appended to")
    out.unlink(missing_ok=True)  # only there when claim_output was given --force
    return record_mcap(
        profile, args.frames, out, tactile=not args.no_tactile, timeout_s=args.timeout,
        settings=parse_settings(args.set), compression=args.compression,
        image_encoding=args.image_encoding, progress=not args.quiet, buffer_mb=args.buffer_mb,
    )


def claim_recording_dir(path: str, append: bool, force: bool) -> Path:
    """``record``'s ``--out``: a recording there is resumed with ``--append`` and refused
    without it (``--force`` never discards recorded frames); otherwise the shared policy."""
    if str(path).strip() and (Path(path) / "manifest.json").is_file():
        if not append:
            raise RecordingError(f"{path} already holds a recording; choose a new --out or pass "
                                 "--append to add frames to it")
        return Path(path)
    return claim_output(path, "directory", force=force)


def run(args: argparse.Namespace) -> int:
    if args.format == "mcap":
        out = claim_output(args.out, "file", force=args.force)
    else:
        out = claim_recording_dir(args.out, args.append, args.force)
    profile = load_profile(args.profile)
    if args.format == "mcap":
        summary = _record_mcap(args, profile, out)
    else:
        summary = record(
            profile, args.frames, out,
            keep_raw=args.raw, timeout_s=args.timeout, settings=parse_settings(args.set),
            append=args.append, scenes=not args.no_scenes, progress=not args.quiet,
            buffer_mb=args.buffer_mb,
        )
    fps = f"{summary.frames / summary.elapsed_s:.1f}" if summary.elapsed_s > 0 else "n/a"
    cam_fps = f"{summary.camera_fps:.1f}" if summary.camera_fps else "n/a"
    print(f"recorded {summary.frames} frame(s) to {out} in {summary.elapsed_s:.2f} s "
          f"({fps} fps written; camera {cam_fps} fps); dropped frames: {summary.dropped}")
    if summary.ended_early:
        print(f"warning: the source ended early: {summary.ended_early}", file=sys.stderr)
    if summary.dropped:
        where = ", ".join(f"{n} before id {fid}" for fid, n in summary.gaps[:10])
        msg = f"the camera dropped {summary.dropped} frame(s) ({where})"
        if args.fail_on_drop:
            raise DeviceError(msg + "; the recording is kept but incomplete")
        where_marked = ("the frames' sequence numbers show the gaps" if args.format == "mcap"
                        else "the manifest marks them (dropped_before)")
        print(f"warning: {msg}; {where_marked}", file=sys.stderr)
    return 0
