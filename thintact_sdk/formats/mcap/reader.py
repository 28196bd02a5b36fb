"""Reading ThinTact MCAP logs, finished or cut short (layout in docs/logging.md).

A finished log is read through its chunk index (``mcap``'s seeking reader). A log whose
writer was killed or ran out of disk has no summary; ``recover=True`` reads it front to
back with ``mcap``'s stream reader and keeps every record up to the last complete chunk,
dropping the torn tail (the same thing ``mcap recover`` does on the command line).
"""

from __future__ import annotations

import contextlib
import os
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.mcap import images, schemas
from thintact_sdk.frames import RawFrame, TactileFrame


@dataclass
class LogMessage:
    """One decoded message: topic, schema name, log time (= header stamp), sequence."""

    topic: str
    schema: str
    log_time_ns: int
    sequence: int
    message: Any


_SCHEMA_OF = {t.name: t.schema for t in schemas.TOPICS}
"""The message type of every ThinTact topic."""


def _damaged_errors() -> tuple[type[BaseException], ...]:
    """What reading or decoding a damaged or foreign message raises (the mcap reader, its
    decompressors, the ROS 2 CDR decoder)."""
    from mcap.exceptions import McapError

    errs: list[type[BaseException]] = [McapError, struct.error, ValueError, EOFError, IndexError,
                                       KeyError, TypeError, RuntimeError, MemoryError, OverflowError,
                                       NameError, AttributeError]
    with contextlib.suppress(ImportError):  # zstandard: the mcap package's optional decompressor
        import zstandard

        errs.append(zstandard.ZstdError)
    with contextlib.suppress(ImportError):  # a damaged schema text: the ROS 2 message parser
        from mcap_ros2._vendor.rosidl_adapter.parser import InvalidSpecification

        errs.append(InvalidSpecification)
    return tuple(errs)


LZ4_MAX_RATIO = 255
"""The most an LZ4 frame can expand (bytes out per byte in): the bound of a frame that does
not store its size."""


def chunk_bound_bytes(compression: str, uncompressed_size: int, head: bytes, compressed_size: int) -> int:
    """The most bytes decompressing a chunk can produce, from its record's fields and the first
    bytes of its data (``head``: at least the compression frame's header).

    The ``mcap`` reader decompresses a whole chunk at once, and a zstd frame that stores its
    content size is decompressed to that size whatever the chunk record declares, and a few
    kilobytes of zstd can hold gigabytes of zeros. So the bound is the largest of the record's
    ``uncompressed_size``, a zstd frame's stored content size, and an LZ4 frame's stored
    size (or :data:`LZ4_MAX_RATIO` × its compressed size when it stores none)."""
    bound = int(uncompressed_size)
    if compression == "zstd":
        import zstandard

        try:
            size = int(zstandard.frame_content_size(head))
        except zstandard.ZstdError:
            size = -1  # not a zstd frame: decompression fails, nothing large is allocated
        bound = max(bound, size)
    elif compression == "lz4":
        import lz4.frame

        try:
            stored = int(lz4.frame.get_frame_info(head)["content_size"])
        except (RuntimeError, ValueError, KeyError):
            stored = 0
        bound = max(bound, stored if stored > 0 else LZ4_MAX_RATIO * int(compressed_size))
    return bound


def _check_chunk(path: Path, compression: str, uncompressed_size: int, head: bytes,
                 compressed_size: int, where: str, limit: int) -> None:
    """Refuse a chunk that would decompress beyond ``limit`` bytes
    (:func:`~thintact_sdk.formats.safe_arrays.array_size_limit`, read once per scan of a log)
    before it is decompressed."""
    from thintact_sdk.formats.safe_arrays import format_bytes

    bound = chunk_bound_bytes(compression, uncompressed_size, head, compressed_size)
    if bound > limit:
        raise RecordingError(f"{path}: the {compression or 'uncompressed'} chunk {where} would "
                             f"decompress to {format_bytes(bound)}, more than this host allows "
                             f"({format_bytes(limit)}); refused before decompressing")


def _check_indexed_chunks(path: Path, summary: Any) -> None:
    """:func:`_check_chunk` on every chunk the summary indexes, reading only each chunk
    record's fixed fields and the first bytes of its data."""
    from thintact_sdk.formats.safe_arrays import array_size_limit

    limit = array_size_limit()
    with open(path, "rb") as f:
        for index in summary.chunk_indexes:
            f.seek(int(index.chunk_start_offset))
            # opcode, record length, start and end times, uncompressed size and CRC, the
            # compression string, the records' length, then the data
            fixed = f.read(1 + 8 + 8 + 8 + 8 + 4 + 4)
            if len(fixed) < 41:
                raise RecordingError(f"{path}: the chunk at byte {index.chunk_start_offset} is cut short")
            uncompressed = struct.unpack_from("<Q", fixed, 25)[0]
            (name_len,) = struct.unpack_from("<I", fixed, 37)
            if name_len > 64:
                raise RecordingError(f"{path}: the chunk at byte {index.chunk_start_offset} names a "
                                     f"{name_len}-byte compression")
            compression = f.read(name_len).decode("utf-8", "replace")
            field = f.read(8)
            if len(field) < 8:
                raise RecordingError(f"{path}: the chunk at byte {index.chunk_start_offset} is cut short")
            (length,) = struct.unpack("<Q", field)
            _check_chunk(path, compression, uncompressed, f.read(32), length,
                         f"at byte {index.chunk_start_offset}", limit)


def _records(path: Path, torn: list[str], open_chunks: bool) -> Iterator[Any]:
    """Every complete record of ``path`` in file order, stopping at a torn tail.

    With ``open_chunks`` each chunk (its CRC checked) is replaced by the records inside it.
    Why reading stopped early, if it did, is appended to ``torn``.
    """
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader, breakup_chunk

    from thintact_sdk.formats.safe_arrays import array_size_limit

    limit = array_size_limit() if open_chunks else 0
    with open(path, "rb") as f:
        records = StreamReader(f, emit_chunks=True).records
        while True:
            try:
                record = next(records)
                if open_chunks and isinstance(record, Chunk):
                    _check_chunk(path, record.compression, record.uncompressed_size, record.data[:32],
                                 len(record.data), f"ending at byte {f.tell()}", limit)
                    inner = breakup_chunk(record, validate_crc=True)
                else:
                    inner = [record]
            except StopIteration:
                return
            except _damaged_errors() as err:
                torn.append(f"{type(err).__name__}: {err}")
                return
            yield from inner


class McapLog:
    """A ThinTact MCAP log opened for reading.

    Parameters
    ----------
    path
        The ``.mcap`` file.
    recover
        Read a log without a summary (killed writer, full disk) up to its last complete
        chunk instead of raising.

    Attributes
    ----------
    summary
        ``mcap`` summary (statistics, chunk indexes, channels), None for a torn log.
    metadata
        Metadata records by name (``"thintact"``: format, clock, units).
    attachments
        Attachment bytes by name (``profile.json``, ``calibration/…``, ``tactile/…``).
    torn
        Why reading stopped early (a torn log read with ``recover``), else None.

    Raises
    ------
    RecordingError
        When the file is missing, not MCAP, or torn and ``recover`` is false.
    """

    def __init__(self, path: str | os.PathLike[str], recover: bool = False) -> None:
        from mcap.exceptions import McapError
        from mcap.reader import make_reader

        self.path = Path(path)
        if not self.path.is_file():
            raise RecordingError(f"MCAP log not found: {self.path}")
        self.torn: str | None = None
        self.summary: Any = None
        unreadable: tuple[type[BaseException], ...] = (*_damaged_errors(), OSError)
        try:
            with open(self.path, "rb") as f:
                reader = make_reader(f)
                reader.get_header()
                self.summary = reader.get_summary()
                if self.summary is not None:
                    _check_indexed_chunks(self.path, self.summary)
                    self.metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
                    self.attachments = {a.name: bytes(a.data) for a in reader.iter_attachments()}
        except unreadable as err:  # a record declaring gigabytes: MemoryError
            if isinstance(err, McapError) and "magic" in str(err) and self.path.stat().st_size:
                with open(self.path, "rb") as f:
                    if f.read(8) != b"\x89MCAP0\r\n":
                        raise RecordingError(f"{self.path} is not an MCAP file") from None
            self.summary = None
        if self.summary is None:
            if not recover:
                raise RecordingError(
                    f"{self.path} has no summary (its writer was killed or ran out of disk); "
                    "open it with recover=True to read it up to its last complete chunk"
                )
            from mcap.records import Attachment, Metadata

            torn: list[str] = []
            self.metadata, self.attachments = {}, {}
            for record in _records(self.path, torn, open_chunks=False):
                if isinstance(record, Metadata):
                    self.metadata[record.name] = dict(record.metadata)
                elif isinstance(record, Attachment):
                    self.attachments[record.name] = bytes(record.data)
            self.torn = torn[0] if torn else None

    @property
    def complete(self) -> bool:
        """True when the log has its summary (it was closed properly)."""
        return self.summary is not None

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[LogMessage]:
        """Every message on ``topics`` (default all), ROS 2 decoded.

        In log-time order; a torn log is read in file order, which is log-time order for
        the logs :class:`~thintact_sdk.formats.mcap.McapLogWriter` writes (one stream, in time).
        """
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        wanted = None if topics is None else set(topics)
        if self.summary is not None:
            with open(self.path, "rb") as f:
                reader = make_reader(f, decoder_factories=[DecoderFactory()])
                found = reader.iter_decoded_messages(topics=None if wanted is None else sorted(wanted))
                while True:
                    try:
                        schema, channel, message, decoded = next(found)
                    except StopIteration:
                        return
                    except _damaged_errors() as err:
                        raise self._damaged(err) from None
                    yield self._checked(LogMessage(channel.topic, schema.name if schema else "",
                                                   message.log_time, message.sequence, decoded))
        from mcap.records import Channel, Message, Schema

        factory = DecoderFactory()
        schemas_by_id: dict[int, Any] = {}
        channels: dict[int, Any] = {}
        for record in _records(self.path, [], open_chunks=True):
            if isinstance(record, Schema):
                schemas_by_id[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                chan = channels.get(record.channel_id)
                if chan is None or (wanted is not None and chan.topic not in wanted):
                    continue
                schema_rec = schemas_by_id.get(chan.schema_id)
                try:
                    decode = factory.decoder_for(chan.message_encoding, schema_rec)
                    if decode is None:
                        raise RecordingError(f"{self.path}: no ROS 2 decoder for topic {chan.topic}")
                    decoded = decode(record.data)
                except _damaged_errors() as err:
                    raise self._damaged(err) from None
                yield self._checked(LogMessage(chan.topic, schema_rec.name if schema_rec else "",
                                               record.log_time, record.sequence, decoded))

    def _damaged(self, err: BaseException) -> RecordingError:
        """The error for a message that cannot be read (damaged chunk, foreign encoding)."""
        return RecordingError(f"{self.path}: a message cannot be read ({type(err).__name__}: {err})")

    def _checked(self, m: LogMessage) -> LogMessage:
        """``m``, once its schema is the one its ThinTact topic carries (a foreign log can
        put any message type on ``/thintact/raw``)."""
        want = _SCHEMA_OF.get(m.topic)
        if want is not None and m.schema != want:
            raise RecordingError(f"{self.path}: topic {m.topic} holds {m.schema or 'schemaless'} "
                                 f"messages; a ThinTact log holds {want} there")
        return m

    @property
    def stamp_offset_ns(self) -> int:
        """Stamp minus capture-clock time (``time.monotonic_ns``) of every frame, ns.

        ``wall_minus_clock_ns`` for a log stamped in wall time (the default since
        ``stamps`` metadata exists), 0 for one stamped on the capture clock (older logs).
        """
        meta = self.metadata.get("thintact", {})
        text = meta.get("stamp_minus_capture_ns", "0")
        try:
            return int(text)
        except ValueError:
            raise RecordingError(f"{self.path}: metadata thintact.stamp_minus_capture_ns is "
                                 f"{text!r}, not an integer") from None

    def _msb_shift(self) -> int:
        text = self.metadata.get("thintact.raw", {}).get("msb_shift", "0")
        if not text.isdigit() or int(text) > 15:
            raise RecordingError(f"{self.path}: metadata thintact.raw.msb_shift is {text!r}, "
                                 "not 0..15")
        return int(text)

    def message_counts(self) -> dict[str, int]:
        """Messages per topic (from the summary statistics, else by reading the file)."""
        if self.summary is not None and self.summary.statistics is not None:
            counts = self.summary.statistics.channel_message_counts
            unknown = [cid for cid in counts if cid not in self.summary.channels]
            if unknown:
                raise RecordingError(f"{self.path}: the summary counts messages on channel {unknown[0]}, "
                                     "which it does not declare (a damaged summary)")
            return {self.summary.channels[cid].topic: n for cid, n in counts.items()}
        out: dict[str, int] = {}
        for m in self.messages():
            out[m.topic] = out.get(m.topic, 0) + 1
        return out

    def raw_frames(self) -> Iterator[RawFrame]:
        """The ``/thintact/raw`` frames as the camera delivered them (exact DN).

        The MSB alignment of 16-bit data is undone (``msb_shift`` metadata) and
        ``timestamp_ns`` is the capture clock (stamp minus :attr:`stamp_offset_ns`), as
        the live SDK delivers it; ``meta["stamp_ns"]`` is the header stamp (wall time).
        """
        pixel_format = self.metadata.get("thintact.raw", {}).get("pixel_format")
        shift, offset = self._msb_shift(), self.stamp_offset_ns
        for m in self.messages([schemas.RAW.name]):
            enc = str(m.message.encoding)
            fmt = pixel_format if pixel_format else images.pixel_format_of(enc)
            data = images.decode_image(m.message)
            if shift and data.dtype == np.uint16:
                data = np.right_shift(data, shift)
            stamp = images.stamp_ns(m.message.header)
            yield RawFrame(data=data, timestamp_ns=stamp - offset,
                           frame_id=m.sequence, pixel_format=fmt, meta={"stamp_ns": stamp})

    def tactile_frames(self) -> Iterator[TactileFrame]:
        """The tactile frames: image, depth, markers, contact (force, slip when logged).

        In a torn log the last frame is dropped when the tear cut its topics short.
        ``timestamp_ns`` is the capture clock, as in :meth:`raw_frames`.
        """
        offset = self.stamp_offset_ns
        tactile = [t.name for t in schemas.TOPICS if t not in (schemas.RAW, schemas.RAW_PREVIEW)]
        group: dict[str, Any] = {}
        stamp: int | None = None
        for m in self.messages(tactile):
            if stamp is not None and m.log_time_ns != stamp:
                yield _tactile_frame(group, stamp, self.path, offset)
                group = {}
            stamp = m.log_time_ns
            group[m.topic] = m.message
        if group and stamp is not None:
            if self.torn is not None and schemas.CONTACT_TOPIC.name not in group:
                return  # the torn tail cut the last frame's topics short
            yield _tactile_frame(group, stamp, self.path, offset)


def _tactile_frame(group: dict[str, Any], stamp: int, path: Path, offset: int = 0) -> TactileFrame:
    missing = [t.name for t in (schemas.IMAGE_TOPIC, schemas.DEPTH, schemas.MARKERS_TOPIC,
                                schemas.CONTACT_TOPIC) if t.name not in group]
    if missing:
        raise RecordingError(f"{path}: the tactile frame at {stamp} ns has no {', '.join(missing)}")
    image = images.decode_image(group[schemas.IMAGE_TOPIC.name])
    if image.dtype == np.uint8:
        image = image.astype(np.float32) / np.float32(255.0)
    depth = images.decode_image(group[schemas.DEPTH.name])
    if not (np.isfinite(image).all() and np.isfinite(depth).all()):  # a writer never logs NaN
        raise RecordingError(f"{path}: the tactile frame at {stamp} ns holds NaN or infinite "
                             "image or depth values (a damaged message)")
    markers, contact = group[schemas.MARKERS_TOPIC.name], group[schemas.CONTACT_TOPIC.name]
    force = group.get(schemas.FORCE.name)
    slip = group.get(schemas.SLIP_TOPIC.name)
    latency = float(contact.latency_ms)
    return TactileFrame(
        image=image,
        depth_mm=depth,
        marker_positions_mm=np.asarray(markers.positions_mm, np.float32).reshape(-1, 2),
        marker_displacements_mm=np.asarray(markers.displacements_mm, np.float32).reshape(-1, 2),
        contact=bool(contact.contact),
        contact_area_mm2=float(contact.contact_area_mm2),
        timestamp_ns=stamp - offset,
        frame_id=int(contact.camera_frame_id),
        shear_direction_rad=float(contact.shear_direction_rad),
        latency_ms=None if np.isnan(latency) else latency,
        force_n=None if force is None else np.array(
            [force.wrench.force.x, force.wrench.force.y, force.wrench.force.z]),
        slip_ratio=None if slip is None else float(slip.slip_ratio),
    )
