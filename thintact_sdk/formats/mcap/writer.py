"""Writing ThinTact MCAP logs (ROS 2 message encodings; layout in docs/logging.md).

::

    from thintact_sdk.formats.mcap import McapLogWriter
    with thintact.open("virtual-finger") as finger, McapLogWriter("press.mcap", finger.profile) as log:
        raw = finger.read_raw()
        log.write_raw(raw)
        log.write_tactile(finger.process(raw))

The file is chunked (uncompressed by default) with a chunk index, message indexes and summary
statistics. Every chunk goes to the operating system as soon as it is complete, so a
killed process or a full disk leaves a file readable up to its last complete chunk
(:func:`thintact_sdk.formats.mcap.reader.read_log` with ``recover=True``).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from thintact_sdk import __version__
from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.mcap import images, schemas
from thintact_sdk.formats.mcap.attachments import calibration_files, media_type, profile_attachment
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.frames import RawFrame, TactileFrame

COMPRESSIONS = ("none", "lz4", "zstd")
DEFAULT_CHUNK_BYTES = 4 * 2**20
CLOCK = "host monotonic clock, ns (time.monotonic_ns); wall time = stamp + wall_minus_clock_ns"
"""``clock`` metadata of a log stamped on the capture clock (``stamps="monotonic"``, older logs)."""
WALL_CLOCK = ("wall clock, ns since the Unix epoch (ROS time); capture clock (time.monotonic_ns) "
              "= stamp - wall_minus_clock_ns")
"""``clock`` metadata of a log stamped in wall time (the default)."""
STAMPS = ("wall", "monotonic")


class _ChunkSink:
    """The writer's output stream: every write goes to the OS at once and is counted.

    The ``mcap`` writer writes a whole chunk record per call, so after each call the file
    on disk ends at a record boundary, whatever happens to this process next.
    """

    def __init__(self, stream: IO[bytes]) -> None:
        self._stream = stream
        self.bytes_written = 0

    def write(self, data: bytes) -> int:
        self._stream.write(data)
        flush = getattr(self._stream, "flush", None)
        if flush is not None:
            flush()
        self.bytes_written += len(data)
        return len(data)

    def tell(self) -> int:
        return self._stream.tell()

    def flush(self) -> None:
        flush = getattr(self._stream, "flush", None)
        if flush is not None:
            flush()


@dataclass
class LogStats:
    """What a writer wrote: frames (raw or tactile), messages and bytes."""

    frames: int = 0
    messages: int = 0
    bytes_written: int = 0
    finished: bool = False
    """True when the summary (chunk index, statistics) was written."""


class McapLogWriter:
    """Writes one sensor's frames into an MCAP file with ROS 2 (CDR) message encodings.

    Parameters
    ----------
    output
        File path (created, replaced if present) or a writable binary stream with ``tell``.
    profile
        The sensor's profile: attached as ``profile.json``; its name is every header's
        ``frame_id``.
    compression
        Chunk compression: ``"none"`` (default: raw sensor noise barely compresses, and
        compression costs throughput, docs/logging.md), ``"lz4"`` or ``"zstd"`` (a third
        smaller on raw frames, ten times slower).
    chunk_bytes
        Uncompressed size at which a chunk is closed and written (default 4 MiB).
    image_encoding
        Reconstruction encoding: ``"rgb8"`` (default, viewable everywhere) or ``"32FC3"``
        (exact float32 display units).
    attach_calibration
        Attach the decoder's calibration bundle and the tactile LUT (default true).
    stamps
        ``"wall"`` (default): header stamps and log times in wall/ROS time, ns since the
        Unix epoch, so the log lines up with a robot's bag: each frame's capture time
        (``time.monotonic_ns``) plus ``wall_minus_clock_ns``, taken once when the writer
        opens (metadata ``thintact``; frames are not re-stamped from a jumping wall clock).
        ``"monotonic"``: the capture clock itself (the stamps of older logs).
    msb_align
        Shift 16-bit raw frames of fewer significant bits (``BayerRG12``: 12) left so they
        fill 16 bits (default true); the shift is the ``msb_shift`` of the ``thintact.raw``
        metadata and :class:`~thintact_sdk.formats.mcap.McapLog` undoes it.
    raw_preview
        Also write ``/thintact/raw_preview`` (``rgb8``) for raw frames common viewers cannot
        decode (``bayer_*16``, ``rgb16``). Default None: exactly for those; False: never.

    Raises
    ------
    RecordingError
        When the file cannot be written (no space, no permission); the message says how
        many frames are in the file.
    """

    def __init__(
        self,
        output: str | os.PathLike[str] | IO[bytes],
        profile: Profile,
        *,
        compression: str = "none",
        chunk_bytes: int = DEFAULT_CHUNK_BYTES,
        image_encoding: str = "rgb8",
        attach_calibration: bool = True,
        stamps: str = "wall",
        msb_align: bool = True,
        raw_preview: bool | None = None,
    ) -> None:
        from mcap.writer import CompressionType
        from mcap_ros2.writer import Writer

        if compression not in COMPRESSIONS:
            raise RecordingError(f"compression must be one of {', '.join(COMPRESSIONS)}, "
                                 f"not {compression!r}")
        images.check_reconstruction_encoding(image_encoding)
        if stamps not in STAMPS:
            raise RecordingError(f"stamps must be 'wall' or 'monotonic', not {stamps!r}")
        self.wall_minus_clock_ns = time.time_ns() - time.monotonic_ns()
        self.stamp_offset_ns = self.wall_minus_clock_ns if stamps == "wall" else 0
        """Added to every capture-clock time to give its stamp."""
        self.stamps = stamps
        self.msb_align = msb_align
        self.raw_preview = raw_preview
        self.profile = profile
        self.image_encoding = image_encoding
        self.frame_id = profile.name
        self.stats = LogStats()
        self._raw_formats: set[str] = set()
        self._failed: str | None = None
        self._owned: IO[bytes] | None = None
        if isinstance(output, (str, os.PathLike)):
            self.where = str(output)
            try:
                Path(output).parent.mkdir(parents=True, exist_ok=True)
                self._owned = open(output, "wb")  # noqa: SIM115 - closed in close()
            except OSError as err:
                raise RecordingError(f"cannot create {output}: {err.strerror or err}") from None
            stream: IO[bytes] = self._owned
        else:
            self.where = str(getattr(output, "name", "the output stream"))
            stream = output
        self._sink = _ChunkSink(stream)
        kind = {"lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD,
                "none": CompressionType.NONE}[compression]
        self._schemas: dict[str, Any] = {}
        self._guard(lambda: self._start(Writer, kind, chunk_bytes, attach_calibration))

    def _start(self, writer_cls: Any, kind: Any, chunk_bytes: int, attach: bool) -> None:
        self._writer = writer_cls(self._sink, chunk_size=chunk_bytes, compression=kind)
        for name, text in schemas.DEFINITIONS.items():
            self._schemas[name] = self._writer.register_msgdef(name, text)
        self._writer.add_metadata("thintact", {
            "format": schemas.LOG_FORMAT,
            "sdk_version": __version__,
            "profile": self.profile.name,
            "clock": WALL_CLOCK if self.stamps == "wall" else CLOCK,
            "stamps": self.stamps,
            "wall_minus_clock_ns": str(self.wall_minus_clock_ns),
            "stamp_minus_capture_ns": str(self.stamp_offset_ns),
            "depth_unit": "mm",
            "reconstruction_encoding": self.image_encoding,
        })
        now = time.time_ns()
        name, media, data = profile_attachment(self.profile)
        self._writer.add_attachment(now, now, name, media, data)
        if attach:
            for name, path in calibration_files(self.profile):
                self._writer.add_attachment(now, now, name, media_type(path), path.read_bytes())

    # -- writing ----------------------------------------------------------------------
    def _guard(self, action: Any) -> None:
        """Run a write; an OSError (disk full, ...) ends the log with a RecordingError."""
        if self._failed is not None:
            raise RecordingError(self._failed)
        try:
            action()
        except OSError as err:
            self._failed = (
                f"writing {self.where} failed after {self.stats.frames} frame(s): "
                f"{err.strerror or err}; the file holds the frames up to its last complete "
                "chunk (read it with thintact_sdk.formats.mcap.McapLog(path, recover=True))"
            )
            self._close_stream()
            raise RecordingError(self._failed) from None

    def _message(self, topic: schemas.Topic, msg: dict[str, Any], stamp: int, seq: int) -> None:
        self._writer.write_message(topic.name, self._schemas[topic.schema], msg,
                                   log_time=int(stamp), publish_time=int(stamp),
                                   sequence=int(seq) & 0xFFFFFFFF)
        self.stats.messages += 1

    def write_raw(self, raw: RawFrame) -> None:
        """Write the camera frame to ``/thintact/raw`` (and ``/thintact/raw_preview``).

        Stamp: ``raw.timestamp_ns`` plus :attr:`stamp_offset_ns`.
        """
        stamp = raw.timestamp_ns + self.stamp_offset_ns
        messages, meta = raw_messages(raw, self.frame_id, stamp, msb_align=self.msb_align,
                                      preview=self.raw_preview)

        def write() -> None:
            if raw.pixel_format not in self._raw_formats:
                self._raw_formats.add(raw.pixel_format)
                self._writer.add_metadata("thintact.raw", meta)
            for topic, msg in messages:
                self._message(topic, msg, stamp, raw.frame_id)
            self.stats.frames += 1

        self._guard(write)

    def write_tactile(self, frame: TactileFrame, count_frame: bool = False) -> None:
        """Write a tactile frame's topics, all stamped with ``frame.timestamp_ns``.

        ``/thintact/image``, ``/thintact/depth``, ``/thintact/markers`` and
        ``/thintact/contact`` always; ``/thintact/force`` when ``frame.force_n`` and
        ``/thintact/slip`` when ``frame.slip_ratio`` is set. ``count_frame``: count it in
        :attr:`stats` ``.frames`` (for logs without raw frames).
        """
        stamp, seq = frame.timestamp_ns + self.stamp_offset_ns, frame.frame_id
        messages = tactile_messages(frame, self.frame_id, stamp, self.image_encoding)

        def write() -> None:
            for topic, msg in messages:
                self._message(topic, msg, stamp, seq)
            if count_frame:
                self.stats.frames += 1

        self._guard(write)

    def write_frames(self, frames: Iterable[tuple[RawFrame | None, TactileFrame | None]]) -> None:
        """Write ``(raw, tactile)`` pairs (either may be None)."""
        for raw, tactile in frames:
            if raw is not None:
                self.write_raw(raw)
            if tactile is not None:
                self.write_tactile(tactile, count_frame=raw is None)

    # -- closing ----------------------------------------------------------------------
    def _close_stream(self) -> None:
        if self._owned is not None:
            try:
                self._owned.close()
            except OSError:
                pass
            self._owned = None
        self.stats.bytes_written = self._sink.bytes_written

    def close(self) -> LogStats:
        """Write the last chunk and the summary (chunk index, statistics); close the file.

        After a write error the file is closed as it is (no summary) and the error is
        not raised again.
        """
        if self._failed is None and not self.stats.finished:
            self._guard(self._writer.finish)
            self.stats.finished = True
        self._close_stream()
        return self.stats

    def __enter__(self) -> McapLogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


Messages = list[tuple[schemas.Topic, dict[str, Any]]]
"""``(topic, message dict for the ROS 2 encoder)`` pairs of one frame."""


def raw_messages(raw: RawFrame, frame_id: str, stamp: int, *, msb_align: bool = True,
                 preview: bool | None = None) -> tuple[Messages, dict[str, str]]:
    """The raw topics of a camera frame and its ``thintact.raw`` metadata.

    ``/thintact/raw`` (16-bit data MSB-aligned with ``msb_align``) and, with ``preview``
    (None: when the encoding is one viewers cannot decode), ``/thintact/raw_preview``.
    Shared by :class:`McapLogWriter` and the live server (:mod:`thintact_sdk.apps.foxglove_live`).

    Raises
    ------
    RecordingError
        For a frame without a ROS encoding, or values beyond its pixel format's bit depth.
    """
    encoding = images.raw_encoding(raw.data, raw.pixel_format)
    bits = images.bit_depth(raw.pixel_format, raw.data.dtype)
    data, shift = raw.data, 0
    if msb_align:
        data, shift = images.msb_align(raw.data, bits, f"raw frame {raw.frame_id} "
                                       f"({raw.pixel_format})")
    messages: Messages = [(schemas.RAW, images.image_message(data, encoding, stamp, frame_id))]
    if preview or (preview is None and images.needs_preview(encoding)):
        rgb = images.preview_rgb8(raw.data, raw.pixel_format, bits)
        messages.append((schemas.RAW_PREVIEW, images.image_message(rgb, "rgb8", stamp, frame_id)))
    meta = {"pixel_format": raw.pixel_format, "encoding": encoding, "bit_depth": str(bits),
            "msb_shift": str(shift)}
    return messages, meta


def tactile_messages(frame: TactileFrame, frame_id: str, stamp: int,
                     image_encoding: str = "rgb8") -> Messages:
    """The tactile topics of ``frame``, every header stamped ``stamp`` (ns).

    Shared by :class:`McapLogWriter` and the live server (:mod:`thintact_sdk.apps.foxglove_live`).
    """
    fid = frame_id
    image = images.reconstruction_array(frame.image, image_encoding)
    messages: Messages = [
        (schemas.IMAGE_TOPIC, images.image_message(image, image_encoding, stamp, fid)),
        (schemas.DEPTH, images.image_message(np.asarray(frame.depth_mm, np.float32),
                                             "32FC1", stamp, fid)),
        (schemas.MARKERS_TOPIC, _markers_message(frame, fid, stamp)),
        (schemas.CONTACT_TOPIC, _contact_message(frame, fid, stamp)),
    ]
    if frame.force_n is not None:
        fx, fy, fz = (float(v) for v in np.asarray(frame.force_n, float).reshape(3))
        messages.append((schemas.FORCE, {
            "header": images.header(stamp, fid),
            "wrench": {"force": {"x": fx, "y": fy, "z": fz},
                       "torque": {"x": 0.0, "y": 0.0, "z": 0.0}},
        }))
    if frame.slip_ratio is not None:
        from thintact_sdk.tactile.interpretation.slip import is_slipping

        ratio = float(frame.slip_ratio)
        messages.append((schemas.SLIP_TOPIC, {"header": images.header(stamp, fid),
                                              "slip_ratio": ratio,
                                              "slipping": is_slipping(ratio)}))
    return messages


def _markers_message(frame: TactileFrame, frame_id: str, stamp: int) -> dict[str, Any]:
    pos = np.asarray(frame.marker_positions_mm, np.float32).reshape(-1, 2)
    disp = np.asarray(frame.marker_displacements_mm, np.float32).reshape(-1, 2)
    return {
        "header": images.header(stamp, frame_id),
        "count": int(pos.shape[0]),
        "positions_mm": pos.ravel().tolist(),
        "displacements_mm": disp.ravel().tolist(),
    }


def _contact_message(frame: TactileFrame, frame_id: str, stamp: int) -> dict[str, Any]:
    disp = np.asarray(frame.marker_displacements_mm, np.float64).reshape(-1, 2)
    finite = disp[np.all(np.isfinite(disp), axis=1)]
    mean = finite.mean(axis=0) if len(finite) else np.zeros(2)
    depth = np.asarray(frame.depth_mm)
    return {
        "header": images.header(stamp, frame_id),
        "camera_frame_id": int(frame.frame_id),
        "contact": bool(frame.contact),
        "contact_area_mm2": float(frame.contact_area_mm2),
        "max_depth_mm": float(np.nanmax(depth)) if depth.size else 0.0,
        "shear_direction_rad": float(frame.shear_direction_rad),
        "mean_displacement_mm": {"x": float(mean[0]), "y": float(mean[1]), "z": 0.0},
        "latency_ms": float(frame.latency_ms) if frame.latency_ms is not None else float("nan"),
    }
