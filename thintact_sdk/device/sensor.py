"""The robot API: one :class:`Sensor` per ThinTact finger.

::

    import thintact_sdk as thintact
    with thintact.open("virtual-finger") as finger:
        frame = finger.read()                      # TactileFrame
        for frame in finger.stream(max_frames=100):
            if frame.contact: ...

A sensor builds everything from its profile through the plugin registry: the camera
(``profile.camera``), the LED controller (``profile.light``, optional), the decoder
(``profile.decoder``) and the tactile interpreter with the device's LUT
(``calibrations/<device>/tactile/lut.npz``, see :mod:`thintact_sdk.tactile.calibration.store`). It
works the same on the virtual sensor, on recordings (``replay``) and on real cameras.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_sdk.device.cameras import (
    FrameGapCounter,
    camera_is_simulated,
    create_camera,
    to_measurement,
)
from thintact_sdk.device.registry import PluginRegistry, get_registry
from thintact_sdk.errors import DeviceError, InvalidValueError, ProfileError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.frames import Measurement, RawFrame, TactileFrame
from thintact_sdk.host.compute_threads import (
    PIPELINE_SHARES_CORES_UP_TO,
    decode_workers,
    prepare_worker_thread,
    single_threaded_kernels,
    usable_cores,
)
from thintact_sdk.interfaces import Camera, Decoder, DecoderInput, LightController
from thintact_sdk.pixels.bayer import planes_to_rgb
from thintact_sdk.tactile.calibration.store import lut_for_profile
from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT

AGE_HISTORY = 10_000  # delivered frames whose age StreamStats keeps


@dataclass
class StreamStats:
    """Frame accounting and timing of :meth:`Sensor.stream`.

    Attributes
    ----------
    captured
        Raw frames the capture thread received.
    camera_dropped
        Frames the camera lost before delivering (gaps in its frame ids).
    skipped
        Frames replaced by a newer one between pipeline stages (binning, decode,
        interpretation) before the next stage got to them.
    processed
        Tactile frames computed.
    consumer_dropped
        Tactile frames replaced by a newer one before the consumer took them.
    delivered
        Tactile frames handed to the consumer.
    age_ms
        Per delivered frame (the last ``AGE_HISTORY``): ms from its arrival from the camera
        (host clock) to its delivery.
    waited_ms_max
        Longest time a delivered frame waited, finished, for the consumer (a newer finished
        frame replaces it, so this stays within one output period of the pipeline).
    warm_up_s
        Seconds spent building and warming up the decoder before the first read (not
        counted against the read timeout).
    decode_workers
        Decode workers of the pipeline (:func:`thintact_sdk.host.compute_threads.decode_workers`);
        with more than one, each decodes whole frames on one kernel thread.
    """

    captured: int = 0
    camera_dropped: int = 0
    skipped: int = 0
    processed: int = 0
    consumer_dropped: int = 0
    delivered: int = 0
    age_ms: deque[float] = field(default_factory=lambda: deque(maxlen=AGE_HISTORY))
    waited_ms_max: float = 0.0
    warm_up_s: float = 0.0
    decode_workers: int = 1

    def age_percentile_ms(self, q: float) -> float:
        """The ``q``-th percentile (0-100) of :attr:`age_ms`; NaN before any delivery."""
        return float(np.percentile(self.age_ms, q)) if self.age_ms else float("nan")


@dataclass
class _InFlight:
    """One frame on its way through the stream pipeline."""

    raw: RawFrame
    arrived_ns: int
    measurement: Measurement | None = None
    image: np.ndarray | None = None
    frame: TactileFrame | None = None
    compute_ms: float = 0.0
    completed_ns: int = 0


class _Latest:
    """A one-item mailbox: put() replaces the item, get() waits for one newer than seen."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: Any = None
        self._seq = 0
        self._taken = 0
        self._newest_ns = -1

    def put(self, item: Any) -> bool:
        """Store ``item``; True when a frame was skipped: it replaced one nobody took, or it is
        itself older than the newest already put (several decode workers finish out of order,
        and an older frame never overtakes a newer one)."""
        with self._cond:
            arrived = getattr(item, "arrived_ns", None)
            if arrived is not None and arrived < self._newest_ns:
                return True
            if arrived is not None:
                self._newest_ns = arrived
            replaced = self._seq > self._taken
            self._item = item
            self._seq += 1
            self._cond.notify_all()
            return replaced

    def get(self, timeout_s: float, stop: threading.Event) -> Any:
        """The newest item not yet taken; None on timeout or when ``stop`` is set."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._seq == self._taken:
                left = deadline - time.monotonic()
                if left <= 0 or stop.is_set():
                    return None
                self._cond.wait(min(left, 0.05))
            self._taken = self._seq
            return self._item

    def wake(self) -> None:
        with self._cond:
            self._cond.notify_all()


def _pipeline_shares_cores() -> bool:
    """True on a host with at most :data:`~thintact_sdk.host.compute_threads.PIPELINE_SHARES_CORES_UP_TO`
    usable cores: frames (streamed or single) decode on one kernel thread there."""
    return usable_cores() <= PIPELINE_SHARES_CORES_UP_TO


class Sensor:
    """A ThinTact sensor opened from a profile.

    Parameters
    ----------
    profile
        The device profile.
    camera_settings
        Overrides merged over ``profile.camera.settings`` (e.g. ``{"slot": "left"}`` to give
        each virtual finger its own scene slot).
    lut
        Photometric-stereo table; default: the device's stored LUT, or for a virtual camera
        without one, a LUT calibrated on the tactile simulator's scenes.
    decoder
        A ready :class:`~thintact_sdk.interfaces.Decoder`; default: built from
        ``profile.decoder``.
    registry
        Plugin registry (default: the process-wide one).
    read_timeout_s
        How long a read waits for the camera.
    reference_frames
        The mean of the first this-many frames (after opening or :meth:`reset_reference`)
        is the no-contact reference; keep the membrane free meanwhile. 4 halves the
        reconstruction noise the reference adds to every depth map.
    """

    def __init__(
        self,
        profile: Profile,
        camera_settings: dict[str, Any] | None = None,
        lut: PhotometricLUT | None = None,
        decoder: Decoder | None = None,
        registry: PluginRegistry | None = None,
        read_timeout_s: float = 2.0,
        reference_frames: int = 1,
    ) -> None:
        self.profile = profile
        self.camera_settings = dict(camera_settings or {})
        self.read_timeout_s = read_timeout_s
        self.reference_frames = reference_frames
        self._registry = registry
        self._lut = lut
        self._decoder = decoder
        self.camera: Camera | None = None
        self.light: LightController | None = None
        self._interpreter: TactileInterpreter | None = None
        self._io_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._kernel_hold: ExitStack | None = None
        self.decode_ms: float | None = None
        """ms one decode took at :meth:`warm_up` on this host (None before)."""
        self._stream_error: BaseException | None = None
        self.stats = StreamStats()
        self.gaps = FrameGapCounter()

    # -- life cycle ------------------------------------------------------------------
    @property
    def registry(self) -> PluginRegistry:
        return self._registry if self._registry is not None else get_registry()

    @property
    def is_open(self) -> bool:
        return self.camera is not None

    def open(self) -> Sensor:
        """Open the camera and, if the profile has one, the LED controller."""
        if self.camera is not None:
            return self
        camera = create_camera(self.profile, self.registry, self.camera_settings)
        camera.open()
        self.camera = camera
        try:
            if self.profile.light is not None:
                cfg = self.profile.light
                light = self.registry.create("light_controller", cfg.plugin, cfg.port, cfg.settings)
                light.open()
                self.light = light
                if cfg.intensities is not None:
                    light.set_all(list(cfg.intensities))
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Stop streaming and release the camera and LED controller. Safe to call twice."""
        self._stop_threads()
        cam, self.camera = self.camera, None
        light, self.light = self.light, None
        if cam is not None:
            cam.close()
        if light is not None:
            light.close()

    def __enter__(self) -> Sensor:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "open" if self.is_open else "closed"
        return f"<Sensor {self.profile.name!r} ({state})>"

    # -- pipeline pieces -------------------------------------------------------------
    @property
    def decoder(self) -> Decoder:
        """The decoder of ``profile.decoder`` (built on first use)."""
        if self._decoder is None:
            cfg = self.profile.decoder
            if cfg is None:
                raise ProfileError(
                    f"profile {self.profile.name!r} has no 'decoder' section; add decoder.plugin "
                    "(a decoder `thintact plugins` lists) and a calibration"
                )
            self._decoder = self.registry.create("decoder", cfg.plugin, self.profile, cfg.settings)
        return self._decoder

    @decoder.setter
    def decoder(self, decoder: Decoder) -> None:
        """Use another decoder from now on (e.g. one built for a benchmark)."""
        self._decoder = decoder

    @property
    def lut(self) -> PhotometricLUT:
        """The photometric-stereo LUT in use (loaded or built on first use)."""
        if self._lut is None:
            self._lut = lut_for_profile(
                self.profile, allow_simulated=camera_is_simulated(self.profile, self.registry))
        return self._lut

    @lut.setter
    def lut(self, lut: PhotometricLUT) -> None:
        """Use another LUT from now on (e.g. one just calibrated); keeps the reference."""
        self._lut = lut
        if self._interpreter is not None:
            self._interpreter.lut = lut

    @property
    def interpreter(self) -> TactileInterpreter:
        """The tactile interpreter (reference frame, marker tracker) of this sensor."""
        if self._interpreter is None:
            self._interpreter = TactileInterpreter(
                self.profile, self.lut, reference_frames=self.reference_frames
            )
        return self._interpreter

    def reset_reference(self) -> None:
        """Make the next ``reference_frames`` frames the no-contact reference."""
        self._interpreter = None

    def _camera(self) -> Camera:
        if self.camera is None:
            raise DeviceError(f"sensor {self.profile.name!r} is not open; call open() first")
        return self.camera

    # -- reading ---------------------------------------------------------------------
    def read_raw(self) -> RawFrame:
        """The next raw frame from the camera."""
        if self._threads:
            raise DeviceError("the sensor is streaming: read frames from stream()")
        with self._io_lock:
            raw = self._camera().read(timeout_s=self.read_timeout_s)
        self.gaps.update(raw.frame_id)
        return raw

    def read_measurement(self) -> Measurement:
        """The next frame as ``R × S × C`` linear DN in the profile's channel layout (black level
        not removed; see :func:`thintact_sdk.device.cameras.to_measurement`)."""
        return to_measurement(self.read_raw(), self.profile)

    def reconstruct(self, measurement: Measurement) -> np.ndarray:
        """Decode a measurement into the ``N × M × C`` float32 scene (display units), one channel
        per sensor channel (4 planes R, Gr, Gb, B for a per-site profile; the tactile stage gets
        them combined to RGB by :func:`thintact_sdk.pixels.bayer.planes_to_rgb`).

        The decoder gets what it declared (:class:`~thintact_sdk.interfaces.DecoderInput`):
        ``decode(measurement.signal())`` for ``input = "signal"``, ``decode(data,
        black_level_dn)`` (the black level folded into the solve) for ``"raw"`` and ``"binned"``.
        A measurement binned for the decoder (``sensor_bin`` = b > 1, made by
        :meth:`decoder_input` for a decoder declaring ``input = "binned"``) holds the ``b × b``
        block means; a binned decoder handed the full measurement bins it itself.

        Raises
        ------
        InvalidValueError
            For a binned measurement the decoder does not solve on (another ``sensor_bin``),
            or a decoder declaring an unknown ``input``.
        """
        decoder = self.decoder
        takes = DecoderInput.of(decoder)
        if measurement.sensor_bin not in (1, takes.sensor_bin):
            raise InvalidValueError(
                f"frame {measurement.frame_id} was binned {measurement.sensor_bin}×{measurement.sensor_bin} "
                f"but decoder {getattr(decoder, 'name', type(decoder).__name__)!r} solves on sensor_bin "
                f"{takes.sensor_bin}; bin it with to_measurement(..., sensor_bin={takes.sensor_bin})")
        if takes.kind == "signal":
            out = decoder.decode(measurement.signal())
        else:
            out = decoder.decode(measurement.data, measurement.black_level_dn)
        return np.asarray(out, np.float32)

    def read_image(self) -> np.ndarray:
        """The next reconstructed membrane image, ``N × M × C`` float32 (see :meth:`reconstruct`)."""
        return self.reconstruct(self.read_measurement())

    def process(self, raw: RawFrame) -> TactileFrame:
        """Raw frame → tactile frame (bin, decode, interpret); sets ``latency_ms``.

        On a host with at most :data:`~thintact_sdk.host.compute_threads.PIPELINE_SHARES_CORES_UP_TO`
        usable cores the decode runs on one kernel thread, as in :meth:`stream`: a product
        split over both cores waits for the busier one, and with the second core taken by
        another job the decode on two threads becomes many times slower than on one
        (the figures are in docs/benchmarks.md, history).
        """
        item = _InFlight(raw, time.monotonic_ns())
        with self.single_frame_kernels():
            for stage in (self._bin_stage, self._decode_stage, self._interpret_stage):
                stage(item)
        assert item.frame is not None
        return item.frame

    @contextmanager
    def single_frame_kernels(self) -> Iterator[None]:
        """The kernel threads a single frame is decoded with (:meth:`process`, benches timing
        its stages): one on a host with at most
        :data:`~thintact_sdk.host.compute_threads.PIPELINE_SHARES_CORES_UP_TO` usable cores (held
        for the block, restored after), the library's otherwise. A decoder built inside the
        block (the first frame) measures its backends on those threads too, as in
        :meth:`stream`."""
        if not _pipeline_shares_cores():
            yield
            return
        with single_threaded_kernels():
            prepare_worker_thread()
            yield

    def warm_up(self) -> float:
        """Build the decoder (its backend selection included), load the LUT and decode one
        black frame, so the first real frame pays none of it. Returns the seconds spent.

        :meth:`stream` calls this before it starts reading, outside the read timeout. The
        decoder is built and timed on the kernel threads frames will be decoded with
        (:meth:`single_frame_kernels`; a stream's own hold where it holds one).
        """
        t0 = time.perf_counter()
        with self.single_frame_kernels():
            s, b = self.profile.sensor, self._input_bin()  # the frames' path: binned for the decoder
            black = Measurement(np.full((s.rows // b, s.cols // b, len(s.channels)), self.profile.noise.black_level_dn,
                                        np.float32), self.profile.noise.black_level_dn, sensor_bin=b)
            self.reconstruct(black)
            t1 = time.perf_counter()
            self.reconstruct(black)  # warm: what a frame costs on this host (chooses decode workers)
            self.decode_ms = (time.perf_counter() - t1) * 1e3
        _ = self.lut
        return time.perf_counter() - t0

    # -- the stages of process() and stream() --------------------------------------------
    def decoder_input(self, raw: RawFrame) -> Measurement:
        """Raw frame → what the decoder declared it takes (:class:`~thintact_sdk.interfaces.DecoderInput`),
        in DN with the black level, for :meth:`reconstruct`: the measurement
        (:func:`~thintact_sdk.device.cameras.to_measurement`), or, for a decoder declaring
        ``input = "binned"`` with ``sensor_bin = b``, its ``b × b`` block means binned straight
        from the mosaic in one pass (``Measurement.sensor_bin = b``). All binning is
        :mod:`thintact_sdk.pixels.bayer`'s. :meth:`reconstruct` then subtracts the black level
        for a ``"signal"`` decoder and hands it to the others.
        :meth:`read_measurement` always gives the measurement."""
        return to_measurement(raw, self.profile, sensor_bin=self._input_bin())

    def _bin_stage(self, item: _InFlight) -> None:
        t0 = time.perf_counter()
        item.measurement = self.decoder_input(item.raw)
        item.compute_ms += (time.perf_counter() - t0) * 1e3

    def _input_bin(self) -> int:
        """The ``b`` to bin raw frames to for this sensor's decoder (1: the measurement)."""
        b = DecoderInput.of(self.decoder).sensor_bin
        s = self.profile.sensor
        return b if s.rows % b == 0 and s.cols % b == 0 else 1

    def _decode_stage(self, item: _InFlight) -> None:
        assert item.measurement is not None
        t0 = time.perf_counter()
        item.image = self.reconstruct(item.measurement)
        item.measurement = None  # the binned frame is not needed any more
        item.compute_ms += (time.perf_counter() - t0) * 1e3

    def _interpret_stage(self, item: _InFlight) -> None:
        assert item.image is not None
        t0 = time.perf_counter()
        raw = item.raw
        frame = self.interpreter.interpret(planes_to_rgb(item.image), raw.timestamp_ns, raw.frame_id)
        item.compute_ms += (time.perf_counter() - t0) * 1e3
        frame.latency_ms = item.compute_ms
        if "scene" in raw.meta:
            frame.meta["scene"] = raw.meta["scene"]
        item.frame = frame

    def read(self) -> TactileFrame:
        """The next tactile frame (the first ``reference_frames`` make the reference)."""
        return self.process(self.read_raw())

    # -- streaming -------------------------------------------------------------------
    def stream(
        self, max_frames: int | None = None, timeout_s: float | None = None
    ) -> Iterator[TactileFrame]:
        """Tactile frames as they come, newest first: a slow consumer never gets a backlog.

        A pipeline of threads (capture → Bayer binning → decode → tactile interpretation)
        works on consecutive frames at once, so the frame rate is bounded by the slowest
        stage, not by the sum of the stages. Between stages a one-frame mailbox holds the
        newest frame only: a stage that falls behind skips to the newest input, so no stale
        frame is queued anywhere, and each ``next()`` returns the newest tactile frame not
        yet returned. Skipped frames are counted in :attr:`stats`; ``frame.meta["age_ms"]``
        is the time from the frame's arrival from the camera to its delivery.

        When one decode (timed at warm-up) does not fit in the camera's frame period, the
        decode stage gets one worker per usable core (``THINTACT_DECODE_WORKERS`` overrides),
        each decoding whole frames on one kernel thread, with OpenBLAS and torch held at one
        thread while it streams (restored after); see :mod:`thintact_sdk.host.compute_threads`.
        On a host with at most :data:`~thintact_sdk.host.compute_threads.PIPELINE_SHARES_CORES_UP_TO`
        usable cores the kernels are held at one thread for every stream, one worker included,
        and the warm-up times the decode that way.
        A frame finished after a newer one is skipped, never delivered out of order.

        The decoder is built and warmed up (:meth:`warm_up`) before the first read, so its
        one-off cost (e.g. measuring the backends on a new host) never counts against
        ``timeout_s``.

        Parameters
        ----------
        max_frames
            Stop after this many frames (default: until the generator is closed).
        timeout_s
            Longest wait for a frame before raising DeviceTimeoutError (default:
            ``read_timeout_s``).
        """
        from thintact_sdk.errors import DeviceTimeoutError

        wait = self.read_timeout_s if timeout_s is None else timeout_s
        self._camera()
        if self._threads:
            raise DeviceError("the sensor is already streaming")
        t0 = time.perf_counter()
        if _pipeline_shares_cores():
            # before the warm-up, which builds the decoder (its backends measured) and times
            # the decode as the stream will run them: on one kernel thread
            self._hold_kernels()
        try:
            self.warm_up()
            warm_up_s = time.perf_counter() - t0
            self._start_threads()
        except BaseException:
            self._release_kernels()
            raise
        self.stats.warm_up_s = warm_up_s
        try:
            n = 0
            while max_frames is None or n < max_frames:
                item = self._frames.get(wait, self._stop)
                if self._stream_error is not None:
                    raise self._stream_error
                if item is None:
                    raise DeviceTimeoutError(
                        f"no tactile frame from {self.profile.name!r} within {wait:.1f} s"
                    )
                frame = item.frame
                now = time.monotonic_ns()
                age_ms = (now - item.arrived_ns) / 1e6
                frame.meta["age_ms"] = age_ms
                self.stats.age_ms.append(age_ms)
                self.stats.waited_ms_max = max(self.stats.waited_ms_max, (now - item.completed_ns) / 1e6)
                self.stats.delivered += 1
                n += 1
                yield frame
        finally:
            self._stop_threads()

    def _start_threads(self) -> None:
        if self._threads:
            raise DeviceError("the sensor is already streaming")
        self._camera()
        self._stop.clear()
        self._stream_error = None
        self._raws = _Latest()
        self._measurements = _Latest()
        self._images = _Latest()
        self._frames = _Latest()
        self.stats = StreamStats()
        name = self.profile.name
        workers = decode_workers(self.decode_ms, self._camera().capabilities().fps)
        self.stats.decode_workers = workers
        if workers > 1:  # frame-parallel decode: one kernel thread per worker, no waits
            self._hold_kernels()
        stages = [
            ("bin", self._raws, self._measurements, self._bin_stage),
            *((f"decode{i}" if workers > 1 else "decode", self._measurements, self._images,
               self._decode_stage) for i in range(workers)),
            ("interpret", self._images, self._frames, self._interpret_stage),
        ]
        self._threads = [threading.Thread(target=self._capture_loop, name=f"{name}-capture", daemon=True)]
        self._threads += [
            threading.Thread(target=self._stage_loop,
                             args=(inbox, outbox, work, label == "interpret", label.startswith("decode")),
                             name=f"{name}-{label}", daemon=True)
            for label, inbox, outbox, work in stages
        ]
        for t in self._threads:
            t.start()

    def _stop_threads(self) -> None:
        if not self._threads:
            return
        self._stop.set()
        for box in (self._raws, self._measurements, self._images, self._frames):
            box.wake()
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads = []
        self._release_kernels()

    def _hold_kernels(self) -> None:
        """Hold OpenBLAS/torch at one thread per decode worker until :meth:`_release_kernels`."""
        if self._kernel_hold is None:
            self._kernel_hold = ExitStack()
            self._kernel_hold.enter_context(single_threaded_kernels())

    def _release_kernels(self) -> None:
        if self._kernel_hold is not None:
            self._kernel_hold.close()
            self._kernel_hold = None

    def _capture_loop(self) -> None:
        cam = self._camera()
        try:
            while not self._stop.is_set():
                with self._io_lock:
                    raw = cam.read(timeout_s=self.read_timeout_s)
                self.stats.captured += 1
                self.stats.camera_dropped += self.gaps.update(raw.frame_id)
                if self._raws.put(_InFlight(raw, time.monotonic_ns())):
                    self.stats.skipped += 1
        except BaseException as err:  # noqa: BLE001 - handed to the consumer
            self._stream_error = err
            self._stop.set()

    def _stage_loop(self, inbox: _Latest, outbox: _Latest, work: Any, last: bool,
                    decode: bool = False) -> None:
        """One pipeline stage: take the newest item of ``inbox``, ``work(item)``, pass it on."""
        try:
            if decode:
                prepare_worker_thread()
            while not self._stop.is_set():
                item = inbox.get(0.1, self._stop)
                if item is None:
                    continue
                work(item)
                if last:
                    self.stats.processed += 1
                    item.completed_ns = time.monotonic_ns()
                if outbox.put(item):
                    if last:
                        self.stats.consumer_dropped += 1
                    else:
                        self.stats.skipped += 1
        except BaseException as err:  # noqa: BLE001 - handed to the consumer
            self._stream_error = err
            self._stop.set()
