"""An MCAP file a user is handed may not be a ThinTact log: another encoding or message type
on a ThinTact topic, or a damaged compressed chunk, is one RecordingError naming the file
(the mcap reader's own exceptions and the CDR decoder's used to escape)."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.mcap import McapLog


def _json_log(path: Path, compression: CompressionType) -> Path:
    """A finished MCAP whose ``/thintact/raw`` channel holds JSON messages."""
    with open(path, "wb") as f:
        w = Writer(f, compression=compression)
        w.start()
        schema = w.register_schema("x", "jsonschema", b"{}")
        channel = w.register_channel("/thintact/raw", "json", schema)
        for i in range(3):
            w.add_message(channel, i, b"{}" * 500, i)
        w.finish()
    return path


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE])
def test_another_encoding_on_a_thintact_topic_is_one_error(compression: CompressionType,
                                                           tmp_path: Path) -> None:
    log = McapLog(_json_log(tmp_path / "json.mcap", compression))
    with pytest.raises(RecordingError, match="json.mcap: a message cannot be read"):
        list(log.raw_frames())


def test_another_ros2_message_type_on_the_raw_topic_is_named(tmp_path: Path) -> None:
    from mcap_ros2.writer import Writer as Ros2Writer

    path = tmp_path / "string.mcap"
    with open(path, "wb") as f:
        w = Ros2Writer(f)
        schema = w.register_msgdef("std_msgs/msg/String", "string data")
        for i in range(2):
            w.write_message("/thintact/raw", schema, {"data": "not an image"}, i, i, i)
        w.finish()
    with pytest.raises(RecordingError, match=r"string.mcap: topic /thintact/raw holds "
                                             r"std_msgs/msg/String messages; a ThinTact log holds"):
        list(McapLog(path).raw_frames())


def test_a_damaged_compressed_chunk_is_one_error(tmp_path: Path) -> None:
    path = _json_log(tmp_path / "z.mcap", CompressionType.ZSTD)
    with open(path, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[0]
    data = bytearray(path.read_bytes())
    # opcode, record length, start and end times, uncompressed size, CRC, "zstd", records length
    start = chunk.chunk_start_offset + 1 + 8 + 16 + 8 + 4 + 4 + len("zstd") + 8
    data[start + 4 : start + 40] = b"\xff" * 36  # inside the zstd frame
    struct.pack_into("<Q", data, chunk.chunk_start_offset + 1 + 8 + 16, 2**40)  # declares 1 TiB
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match="z.mcap"):
        list(McapLog(path).messages())


def _zeros_log(path: Path, compression: CompressionType, mib: int) -> Path:
    """A finished MCAP with one message of ``mib`` MiB of zeros (compresses to kilobytes)."""
    with open(path, "wb") as f:
        w = Writer(f, compression=compression, chunk_size=2**30)
        w.start()
        schema = w.register_schema("x", "jsonschema", b"{}")
        channel = w.register_channel("/x", "json", schema)
        w.add_message(channel, 0, bytes(mib * 2**20), 0)
        w.finish()
    return path


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.LZ4])
def test_a_chunk_that_would_decompress_beyond_memory_is_refused_first(
        compression: CompressionType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A zstd frame storing its size is decompressed to that size whatever the chunk record
    says (a few kilobytes of zstd can hold gigabytes of zeros), so the bound is read from the frame's header:
    here 24 MiB of zeros against a limit of 16 MiB, while the chunk record declares 1 byte."""
    path = _zeros_log(tmp_path / "bomb.mcap", compression, 24)
    assert path.stat().st_size < 2**20
    with open(path, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[0]
    data = bytearray(path.read_bytes())
    struct.pack_into("<Q", data, chunk.chunk_start_offset + 1 + 8 + 16, 1)  # the record lies
    path.write_bytes(bytes(data))
    monkeypatch.setattr("thintact_sdk.formats.safe_arrays.array_size_limit", lambda: 16 * 2**20)
    with pytest.raises(RecordingError, match=r"bomb.mcap: the .* chunk at byte \d+ would decompress "
                                             r"to 24.0 MiB"):
        McapLog(path)
    torn = tmp_path / "torn.mcap"  # no summary: read front to back, each chunk checked
    torn.write_bytes(bytes(data[: chunk.chunk_start_offset + chunk.chunk_length]))
    with pytest.raises(RecordingError, match="would decompress to 24.0 MiB"):
        list(McapLog(torn, recover=True).messages())
    assert McapLog(_zeros_log(tmp_path / "ok.mcap", compression, 2)).complete  # under the limit
