"""``thintact record --format mcap``: capture frames from a profile's camera into an MCAP log.

Each camera frame goes to ``/thintact/raw`` as delivered; with ``tactile`` (default) it is
also turned into a tactile frame by :meth:`thintact_sdk.device.sensor.Sensor.process` (binning,
decoding, photometric stereo, markers) and its image, depth, markers and contact topics
are written with the same stamp. Capture, drop accounting and the progress bar are those
of ``thintact record`` (:func:`thintact_sdk.device.capture_loop.capture_frames`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from thintact_sdk.device.cameras import create_camera
from thintact_sdk.device.capture_loop import RecordSummary, capture_frames
from thintact_sdk.device.sensor import Sensor
from thintact_sdk.errors import RecordingError, ThinTactError
from thintact_sdk.formats.mcap.writer import DEFAULT_CHUNK_BYTES, McapLogWriter
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.frames import RawFrame


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
    raw_preview: bool | None = None,
    chunk_bytes: int = DEFAULT_CHUNK_BYTES,
    progress: bool = True,
    buffer_mb: float = 512.0,
) -> RecordSummary:
    """Record ``frames`` camera frames (and their tactile frames) into the MCAP file ``out``.

    ``raw_preview``: write ``/thintact/raw_preview`` beside raw frames viewers cannot decode
    (``None``: where the raw encoding needs it; ``False``: never, for the highest frame rate).

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
    sink = _McapSink(out, profile, sensor, compression=compression, chunk_bytes=chunk_bytes,
                     image_encoding=image_encoding, raw_preview=raw_preview)
    return capture_frames(camera, profile, frames, sink, saved_in=out, timeout_s=timeout_s,
                          buffer_mb=buffer_mb, progress=progress)


class _McapSink:
    """Writes each raw frame (and, with a sensor, its tactile frame) to an MCAP log."""

    def __init__(self, out: Path, profile: Profile, sensor: Sensor | None, *, compression: str,
                 chunk_bytes: int, image_encoding: str, raw_preview: bool | None) -> None:
        self.out = out
        self.profile = profile
        self.sensor = sensor
        self.options: dict[str, Any] = {"compression": compression, "chunk_bytes": chunk_bytes,
                                        "image_encoding": image_encoding,
                                        "raw_preview": raw_preview}
        self._log: McapLogWriter | None = None

    def start(self) -> None:
        self._log = McapLogWriter(self.out, self.profile, **self.options)

    def write(self, index: int, raw: RawFrame, dropped_before: int) -> None:
        assert self._log is not None
        self._log.write_raw(raw)
        if self.sensor is not None:
            self._log.write_tactile(self.sensor.process(raw))

    def close(self) -> None:
        """Finish the log (summary and index), also after a camera fault."""
        if self._log is not None:
            self._log.close()
