"""``thintact record --format mcap``: capture frames from a profile's camera into an MCAP log.

Each camera frame goes to ``/thintact/raw`` as delivered; with ``tactile`` (default) it is
also turned into a tactile frame by :meth:`thintact_sdk.sensor.Sensor.process` (binning,
decoding, photometric stereo, markers) and its image, depth, markers and contact topics
are written with the same stamp. Capture, drop accounting and the progress bar are those
of ``thintact record`` (:mod:`thintact_sdk.cli.commands.record`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from thintact_sdk.capture import FrameGapCounter, create_camera
from thintact_sdk.cli.commands.record import (
    MAX_GAP_NOTES,
    RecordSummary,
    _BufferedReader,
    _Progress,
)
from thintact_sdk.errors import DeviceError, EndOfStreamError, RecordingError, ThinTactError
from thintact_sdk.mcaplog.writer import DEFAULT_CHUNK_BYTES, McapLogWriter
from thintact_sdk.profile import Profile
from thintact_sdk.sensor import Sensor


def record_mcap(
    profile: Profile,
    frames: int,
    out: Path,
    *,
    tactile: bool = True,
    timeout_s: float = 5.0,
    settings: dict[str, Any] | None = None,
    compression: str = "none",
    image_encoding: str = "rgb8",
    chunk_bytes: int = DEFAULT_CHUNK_BYTES,
    progress: bool = True,
    buffer_mb: float = 512.0,
) -> RecordSummary:
    """Record ``frames`` camera frames (and their tactile frames) into the MCAP file ``out``.

    Raises
    ------
    RecordingError
        When ``out`` exists, or writing fails (disk full: the file keeps every frame up
        to its last complete chunk).
    DeviceError
        When the camera fails; the log is closed properly with every frame before the fault.
    """
    if frames <= 0:
        raise ThinTactError("--frames must be at least 1")
    if out.exists():
        raise RecordingError(f"{out} already exists; choose a new --out (MCAP logs are not appended to)")
    sensor = Sensor(profile, camera_settings=settings) if tactile else None
    camera = create_camera(profile, settings=settings)
    gaps = FrameGapCounter()
    summary = RecordSummary()
    stamps: list[int] = []
    t0 = time.monotonic()
    reader: _BufferedReader | None = None
    log: McapLogWriter | None = None
    try:
        camera.open()
        log = McapLogWriter(out, profile, compression=compression, chunk_bytes=chunk_bytes,
                            image_encoding=image_encoding)
        reader = _BufferedReader(camera, frames, timeout_s, buffer_mb * 2**20)
        with _Progress(frames, enabled=progress) as bar:
            for _ in range(frames):
                try:
                    raw = reader.next()
                except EndOfStreamError as err:
                    summary.ended_early = str(err)
                    break
                missing = gaps.update(raw.frame_id)
                if missing and len(gaps.gaps) <= MAX_GAP_NOTES:
                    bar.note(f"{missing} frame(s) dropped before frame id {raw.frame_id}")
                log.write_raw(raw)
                if sensor is not None:
                    log.write_tactile(sensor.process(raw))
                stamps.append(raw.timestamp_ns)
                summary.frames += 1
                bar.advance(summary.frames, time.monotonic() - t0, gaps.dropped, reader.buffered)
    except DeviceError as err:
        raise type(err)(f"{err} ({summary.frames} frame(s) were saved in {out})") from None
    finally:
        if reader is not None:
            reader.stop()
        camera.close()
        if log is not None:
            log.close()
    summary.elapsed_s = time.monotonic() - t0
    summary.dropped, summary.gaps = gaps.dropped, list(gaps.gaps)
    if len(stamps) > 1 and stamps[-1] > stamps[0]:
        summary.camera_fps = (len(stamps) - 1) * 1e9 / (stamps[-1] - stamps[0])
    return summary
