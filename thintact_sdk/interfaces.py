"""The small typed interfaces every plugin implements.

``Camera``           raw frames with timestamps, counters and exposure metadata.
``LightController``  the sensor's LED intensities.
``Mask``             a mask design (φ vectors, feature size) and how it was made.
``ImagingModel``     forward model scene → measurement (simulator or calibrated T2S).
``Decoder``          measurement → scene (reconstruction algorithms), one entry point ``decode``.
``Display``          shows calibration patterns on an LCD (real or virtual).

Concrete classes come from plugins (see :mod:`thintact_sdk.device.registry`).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from thintact_sdk.frames import RawFrame


@dataclass(frozen=True)
class Range:
    """A closed numeric range with a unit, e.g. exposure 10..1e6 us."""

    min: float
    max: float
    unit: str = ""


@dataclass
class CameraCapabilities:
    """What a camera can do; ``None`` for a range means the device lacks that control."""

    width: int
    height: int
    pixel_formats: list[str]
    pixel_format: str
    fps: float | None = None
    fps_range: Range | None = None
    exposure_range_us: Range | None = None
    gain_range_db: Range | None = None
    missing: list[str] = field(default_factory=list)
    """Profile settings the device could not honour (e.g. ``["ExposureTime"]``)."""


class Camera(abc.ABC):
    """A source of raw frames. Use as a context manager or call open()/close()."""

    name: str = "camera"

    @abc.abstractmethod
    def open(self) -> None:
        """Connect to the device and apply the settings; raises DeviceError on failure."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device. Safe to call twice."""

    @abc.abstractmethod
    def capabilities(self) -> CameraCapabilities:
        """Resolution, pixel format, fps, exposure and gain ranges of the opened device."""

    @abc.abstractmethod
    def read(self, timeout_s: float = 2.0) -> RawFrame:
        """Block until the next frame; raises DeviceTimeoutError or DeviceLostError."""

    def set_exposure_us(self, exposure_us: float) -> None:
        """Set the exposure time (us); raises UnsupportedFeatureError where unsupported."""
        from thintact_sdk.errors import UnsupportedFeatureError

        raise UnsupportedFeatureError(f"{self.name}: exposure control not supported")

    def set_gain_db(self, gain_db: float) -> None:
        """Set the analogue gain (dB); raises UnsupportedFeatureError where unsupported."""
        from thintact_sdk.errors import UnsupportedFeatureError

        raise UnsupportedFeatureError(f"{self.name}: gain control not supported")

    @property
    def is_open(self) -> bool:
        return bool(getattr(self, "_is_open", False))

    def __enter__(self) -> Camera:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LightController(abc.ABC):
    """Sets and reads the intensities of the sensor's LEDs (levels in [0, 1])."""

    @abc.abstractmethod
    def open(self) -> None: ...

    @abc.abstractmethod
    def close(self) -> None: ...

    @property
    @abc.abstractmethod
    def led_count(self) -> int:
        """Number of LEDs driven."""

    @abc.abstractmethod
    def set_intensity(self, index: int, level: float) -> None:
        """Set LED ``index`` (0-based) to ``level`` in [0, 1]."""

    @abc.abstractmethod
    def set_all(self, levels: list[float]) -> None:
        """Set every LED at once; ``len(levels) == led_count``."""

    @abc.abstractmethod
    def get_intensities(self) -> list[float]:
        """Read back the levels the controller applies."""

    def firmware_version(self) -> str:
        return "unknown"

    def __enter__(self) -> LightController:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class Mask:
    """A separable binary mask design.

    Attributes
    ----------
    phi
        ``K`` int8 entries ±1 along x (columns).
    feature_um
        Cell side δ in um.
    phi_rows
        ``K`` ±1 along y; ``None`` means equal to ``phi``.
    design
        Which mask plugin produced it (``"mls"``, ``"random"``, ``"ga"``, ...).
    provenance
        How it was made (seed, generations, fitness, ...).
    """

    phi: np.ndarray
    feature_um: float
    phi_rows: np.ndarray | None = None
    design: str = "custom"
    provenance: dict[str, Any] = field(default_factory=dict)

    @property
    def K(self) -> int:  # noqa: N802
        return int(len(self.phi))

    def pattern(self) -> np.ndarray:
        """``K × K`` uint8 transmittance (1 open, 0 closed), row i along y (paper eq. 1)."""
        rows = self.phi if self.phi_rows is None else self.phi_rows
        return ((np.outer(rows, self.phi) + 1) // 2).astype(np.uint8)


class MaskDesigner(abc.ABC):
    """A mask plugin: produces a :class:`Mask` of length K."""

    name: str = "mask"

    @abc.abstractmethod
    def design(self, K: int, feature_um: float, **options: Any) -> Mask:  # noqa: N803
        ...

    def stored_design(self, device: str) -> tuple[Mask, dict[str, Any]] | None:
        """A design this designer made earlier for the device (profile name) ``device`` and
        ships or keeps, with its record (JSON object: ``design``, ``K``, ``feature_um`` ...);
        ``None`` (the default) when it has none. ``thintact bench reconstruct`` compares the
        profile's mask with every stored design it finds."""
        return None


class ImagingModel(abc.ABC):
    """Forward model: scene (``N × M × C``, display units) → signal (``R × S × C``)."""

    @abc.abstractmethod
    def forward(self, scene: np.ndarray) -> np.ndarray:
        """Noiseless signal for one scene, ``R × S × C`` float64 (model units)."""


DecoderInputKind = Literal["signal", "raw", "binned"]
"""What a decoder takes from a :class:`~thintact_sdk.device.sensor.Sensor` (:attr:`Decoder.input`)."""

DECODER_INPUTS: tuple[str, ...] = ("signal", "raw", "binned")


class Decoder(abc.ABC):
    """Reconstruction: one sensor frame in DN → one scene, through the one entry point :meth:`decode`.

    A decoder declares what it takes in two class (or instance) attributes, and the
    :class:`~thintact_sdk.device.sensor.Sensor` makes exactly that in one place
    (:meth:`~thintact_sdk.device.sensor.Sensor.decoder_input` and
    :meth:`~thintact_sdk.device.sensor.Sensor.reconstruct`):

    ``input = "signal"`` (the default)
        ``decode(signal)``: the profile's ``R × S × C`` float32 measurement in DN *above* black
        (the Sensor subtracts the black level; ``black_level_dn`` is left at 0).
    ``input = "raw"``
        ``decode(frame, black_level_dn)``: the ``R × S × C`` measurement in DN *with* the black
        level (float32 or integer), and that black level in DN; the decoder folds it into its
        solve (no per-frame subtraction).
    ``input = "binned"`` with ``sensor_bin = b`` > 1
        ``decode(frame, black_level_dn)``: the ``b × b`` block means of the measurement,
        ``R/b × S/b × C`` DN with the black level, binned from the camera's Bayer mosaic in one
        pass (``2b × 2b`` cells per colour site, :func:`thintact_sdk.pixels.bayer.bin_sites`),
        and the black level in DN. Callers holding the full ``R × S × C`` frame (calibration,
        benchmarks) may hand that instead; such a decoder tells the two apart by their shape
        and bins a full frame itself (:func:`thintact_sdk.pixels.bayer.block_mean`).

    Outside a Sensor, ``decode(signal)`` (``black_level_dn`` 0: DN above black) works on
    every decoder: that is how calibration and the ``reconstruct`` command call it.
    """

    name: str = "decoder"
    input: DecoderInputKind = "signal"
    """What :meth:`decode` takes from a Sensor: ``"signal"``, ``"raw"`` or ``"binned"`` (above)."""
    sensor_bin: int = 1
    """Block side ``b`` (sensor pixels) of the binned frames an ``input = "binned"`` decoder
    solves on; 1 for the other kinds."""

    @abc.abstractmethod
    def decode(self, frame: np.ndarray, black_level_dn: float = 0.0) -> np.ndarray:
        """Reconstruct one scene, ``N × M × C`` float32 (display units).

        Parameters
        ----------
        frame
            ``R × S × C`` DN (``R/b × S/b × C`` block means for a binned decoder), holding
            ``black_level_dn``.
        black_level_dn
            The black level ``frame`` includes, DN; 0 for a signal above black.
        """


@dataclass(frozen=True)
class DecoderInput:
    """What a decoder declared it takes (:attr:`Decoder.input`, :attr:`Decoder.sensor_bin`),
    read and checked once; a decoder that is not a :class:`Decoder` subclass but has a
    ``decode`` method takes the signal.

    Attributes
    ----------
    kind
        ``"signal"``, ``"raw"`` or ``"binned"``.
    sensor_bin
        ``b`` of a ``"binned"`` decoder (> 1); 1 for the other kinds.
    """

    kind: DecoderInputKind = "signal"
    sensor_bin: int = 1

    @classmethod
    def of(cls, decoder: object) -> DecoderInput:
        """The declaration of ``decoder``.

        Raises
        ------
        InvalidValueError
            For an ``input`` other than the three kinds, or a ``"binned"`` decoder whose
            ``sensor_bin`` is not an integer > 1 (the error names the decoder and the field).
        """
        from thintact_sdk.errors import InvalidValueError

        kind: DecoderInputKind = getattr(decoder, "input", "signal")
        who = f"decoder {getattr(decoder, 'name', type(decoder).__name__)!r}"
        if kind not in DECODER_INPUTS:
            raise InvalidValueError(f"{who}: input must be one of {', '.join(DECODER_INPUTS)}, got {kind!r}")
        if kind != "binned":
            return cls(kind, 1)
        b = getattr(decoder, "sensor_bin", 1)
        if isinstance(b, bool) or not isinstance(b, int | np.integer) or b < 2:
            raise InvalidValueError(f"{who}: input 'binned' needs sensor_bin an integer > 1, got {b!r}")
        return cls("binned", int(b))


@runtime_checkable
class TunableDecoder(Protocol):
    """A decoder whose Tikhonov weight τ (DN²) changes without rebuilding it (closed forms);
    calibration sweeps τ through it."""

    def set_tau(self, tau: float) -> None:
        """Use ``tau`` (DN², > 0) from the next decode on."""
        ...

    def decode(self, frame: np.ndarray, black_level_dn: float = 0.0) -> np.ndarray:
        """Reconstruct one scene, ``N × M × C`` float32 (:meth:`Decoder.decode`)."""
        ...


class Display(abc.ABC):
    """An LCD that shows scene patterns during calibration."""

    @abc.abstractmethod
    def open(self) -> None: ...

    @abc.abstractmethod
    def close(self) -> None: ...

    @abc.abstractmethod
    def show(self, scene: np.ndarray) -> None:
        """Show ``N × M × 3`` values in [0, 1] on the sensing area (one LCD pixel per scene pixel)."""

    def __enter__(self) -> Display:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
