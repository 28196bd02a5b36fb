"""A killed writer or a full disk leaves a log readable up to its last complete chunk."""

from __future__ import annotations

import errno
import io
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_testkit import mini_profile, raw_frame, tactile_frame

from thintact_sdk.apps.cli.main import main
from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.mcap import McapLog, McapLogWriter

HERE = Path(__file__).resolve().parent


def _assert_intact_prefix(log: McapLog, at_least: int) -> int:
    raws = list(log.raw_frames())
    assert len(raws) >= at_least
    for i, raw in enumerate(raws):
        assert raw.frame_id == 100 + i
        np.testing.assert_array_equal(raw.data, raw_frame(i).data)
    return len(raws)


def test_torn_file_reads_exactly_the_complete_chunks(tmp_path):
    full = tmp_path / "full.mcap"
    with McapLogWriter(full, mini_profile(), chunk_bytes=200_000,
                       attach_calibration=False) as log:
        for i in range(8):
            log.write_raw(raw_frame(i))
            log.write_tactile(tactile_frame(i))
    with open(full, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    data = full.read_bytes()
    for k in (1, 2, len(chunks) - 1):
        ci = chunks[k]
        cut = ci.chunk_start_offset + ci.chunk_length // 2  # inside chunk k
        torn = tmp_path / f"torn{k}.mcap"
        torn.write_bytes(data[:cut])
        with pytest.raises(RecordingError, match="recover=True"):
            McapLog(torn)
        log = McapLog(torn, recover=True)
        assert not log.complete and log.torn
        assert log.attachments["profile.json"]
        want = sum(1 for m in McapLog(full).messages(["/thintact/raw"])
                   if m.log_time_ns <= chunks[k - 1].message_end_time)
        assert _assert_intact_prefix(log, want) == want
        # a chunk may close between a frame's raw image and its tactile topics
        contacts = sum(1 for _ in log.messages(["/thintact/contact"]))
        assert want - 1 <= contacts <= want
        assert len(list(log.tactile_frames())) == contacts


WRITER_SCRIPT = """
import sys
sys.path.insert(0, {here!r})
from mcap_testkit import mini_profile, raw_frame, tactile_frame
from thintact_sdk.formats.mcap import McapLogWriter
log = McapLogWriter({path!r}, mini_profile(), chunk_bytes=200_000, attach_calibration=False)
i = 0
while True:
    log.write_raw(raw_frame(i))
    log.write_tactile(tactile_frame(i))
    i += 1
    print(i, flush=True)
"""


def test_killed_writer_leaves_a_readable_log(tmp_path):
    path = tmp_path / "killed.mcap"
    script = WRITER_SCRIPT.format(here=str(HERE), path=str(path))
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        written = 0
        deadline = time.monotonic() + 60
        while written < 12 and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            written = int(line)
        assert written >= 12, "the writer did not get going"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        # the writer may have run ahead of what was read before the kill: count what it printed
        rest = [int(x) for x in proc.stdout.read().split()]
        written = max([written, *rest])
    finally:
        proc.kill()
        proc.wait(timeout=10)
    with pytest.raises(RecordingError, match="no summary"):
        McapLog(path)
    log = McapLog(path, recover=True)
    # 200 kB chunks hold two 160 kB raw frames: at most the open chunk is lost
    got = _assert_intact_prefix(log, written - 3)
    assert got <= written + 1


class _DiskThatFills(io.BytesIO):
    """A stream that accepts ``capacity`` bytes, writes what fits, then fails with ENOSPC."""

    def __init__(self, capacity: int) -> None:
        super().__init__()
        self.capacity = capacity

    def write(self, data) -> int:  # type: ignore[override]
        room = self.capacity - self.tell()
        if len(data) > room:
            super().write(bytes(data[:max(room, 0)]))
            raise OSError(errno.ENOSPC, "No space left on device")
        return super().write(data)


def test_full_disk_stops_with_an_error_and_keeps_the_complete_chunks(tmp_path):
    disk = _DiskThatFills(1_500_000)
    log = McapLogWriter(disk, mini_profile(), chunk_bytes=200_000, attach_calibration=False)
    written = 0
    with pytest.raises(RecordingError, match="No space left on device") as err:
        for i in range(100):
            log.write_raw(raw_frame(i))
            log.write_tactile(tactile_frame(i))
            written += 1
    assert "McapLog(path, recover=True)" in str(err.value)
    assert re.search(r"after (\d+) frame", str(err.value)).group(1) in (str(written), str(written + 1))
    with pytest.raises(RecordingError, match="No space"):
        log.write_raw(raw_frame(99))  # a failed log stays failed
    assert not log.close().finished
    path = tmp_path / "full.mcap"
    path.write_bytes(disk.getvalue())
    assert len(disk.getvalue()) == 1_500_000
    recovered = McapLog(path, recover=True)
    assert _assert_intact_prefix(recovered, written - 3) <= written


@pytest.fixture
def tiny_tmpfs(tmp_path):
    """A 6 MiB tmpfs mounted for the test (root only; skipped where mounting is refused)."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    mnt = tmp_path / f"tmpfs-{uuid.uuid4().hex[:6]}"
    mnt.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=6m", "tmpfs", str(mnt)],
                         capture_output=True, text=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


def test_record_onto_a_full_filesystem(tiny_tmpfs, capsys):
    out = tiny_tmpfs / "log.mcap"
    rc = main(["record", "--profile", "virtual-mini", "--frames", "80", "--format", "mcap",
               "--no-tactile", "--compression", "none", "--set", "fps=0", "--quiet",
               "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert "No space left on device" in err and "last complete chunk" in err
    assert "Traceback" not in err
    log = McapLog(out, recover=True)
    raws = list(log.raw_frames())
    assert 19 <= len(raws) < 80  # a 4 MiB chunk holds 19 frames (raw + rgb8 preview)
    assert all(r.data.shape == (256, 320) for r in raws)


@pytest.mark.parametrize("damage", ["schema field", "nan depth", "huge record"])
def test_a_damaged_log_is_one_recording_error(tmp_path, damage):
    """A damaged schema text ended in the ROS 2 parser's own exceptions, an overwritten depth
    payload gave NaN depth silently, and a record declaring an enormous length ended in
    OverflowError/MemoryError at open."""
    path = tmp_path / "log.mcap"
    with McapLogWriter(path, mini_profile(), compression="none",
                       attach_calibration=False) as log:
        for i in range(2):
            log.write_raw(raw_frame(i))
            log.write_tactile(tactile_frame(i))
    data = bytearray(path.read_bytes())
    if damage == "schema field":
        k = data.index(b"contact_area_mm2")
        while k >= 0:  # the data section's schema and the summary's copy
            data[k] = ord("C")  # a field name must start lower-case
            k = data.find(b"contact_area_mm2", k + 1)
    elif damage == "nan depth":
        depth = np.asarray(tactile_frame(1).depth_mm, np.float32).tobytes()
        k = data.rindex(depth[-64:])  # the last frame's depth payload, uncompressed
        data[k:k + 4] = np.float32(np.nan).tobytes()
    else:
        data[8 + 1:8 + 9] = (2**63 - 1).to_bytes(8, "little")  # the header record's length
    path.write_bytes(bytes(data))
    if damage == "huge record":  # no summary can be read; recovering reads nothing, and says why
        with pytest.raises(RecordingError, match="has no summary"):
            McapLog(path)
        log = McapLog(path, recover=True)
        assert not list(log.raw_frames()) and "exceeds limit" in str(log.torn)
        return
    with pytest.raises(RecordingError, match=str(path.name)):
        log = McapLog(path, recover=True)
        log.message_counts()
        list(log.raw_frames())
        list(log.tactile_frames())
