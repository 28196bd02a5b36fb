"""The small typed interfaces every plugin implements.

``Camera``           raw frames with timestamps, counters and exposure metadata.
``LightController``  the sensor's LED intensities.
``Mask``             a mask design (φ vectors, feature size) and how it was made.
``ImagingModel``     forward model scene → measurement (simulator or calibrated T2S).
``Decoder``          measurement → scene (reconstruction algorithms).
``Display``          shows calibration patterns on an LCD (real or virtual).

Concrete classes come from plugins (see :mod:`thintact_sdk.device.registry`).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

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


class Decoder(abc.ABC):
    """Reconstruction: measurement signal (``R × S × C``, DN above black) → scene."""

    name: str = "decoder"

    @abc.abstractmethod
    def decode(self, signal: np.ndarray) -> np.ndarray:
        """Reconstruct one scene, ``N × M × C`` float32."""


@runtime_checkable
class RawDecoder(Protocol):
    """A decoder that also takes raw binned DN and folds the black level into the solve
    (no per-frame subtraction); :meth:`thintact_sdk.device.sensor.Sensor.reconstruct` prefers it."""

    def decode_raw(self, raw: np.ndarray, black_level_dn: float) -> np.ndarray:
        """``R × S × C`` DN with the black level included → ``N × M × C`` float32."""
        ...


@runtime_checkable
class BinnedInputDecoder(Protocol):
    """A decoder that solves on the sensor binned ``b × b`` (``sensor_bin`` = b > 1) and so
    takes the binned frame directly.

    :meth:`thintact_sdk.device.sensor.Sensor.process` and :meth:`~thintact_sdk.device.sensor.Sensor.stream`
    then bin the camera's Bayer mosaic ``2b × 2b`` per colour site in one pass
    (:func:`thintact_sdk.pixels.bayer.bin_bayer` with ``block=b``) instead of ``2 × 2`` and then
    ``b × b`` again in the decoder, and hand the result, a :class:`~thintact_sdk.frames.Measurement`
    with ``sensor_bin = b``, to :meth:`decode_binned`. ``decode`` and ``decode_raw`` still take
    the profile's full ``R × S × C`` measurement; a decoder without this capability (or with
    ``sensor_bin`` 1) gets exactly that.
    """

    sensor_bin: int
    """Block side ``b`` (sensor pixels) of the binning the decoder solves on."""

    def decode_binned(self, binned: np.ndarray, black_level_dn: float) -> np.ndarray:
        """``R/b × S/b × C`` block means of the measurement in DN, black level included →
        ``N × M × C`` float32."""
        ...


def binned_input(decoder: object) -> int:
    """The ``b`` of a :class:`BinnedInputDecoder` that solves on a binned sensor (> 1), else 1."""
    if isinstance(decoder, BinnedInputDecoder):
        return max(1, int(decoder.sensor_bin))
    return 1


@runtime_checkable
class TunableDecoder(Protocol):
    """A decoder whose Tikhonov weight τ (DN²) changes without rebuilding it (closed forms);
    calibration sweeps τ through it."""

    def set_tau(self, tau: float) -> None:
        """Use ``tau`` (DN², > 0) from the next decode on."""
        ...

    def decode(self, signal: np.ndarray) -> np.ndarray:
        """Reconstruct one scene, ``N × M × C`` float32."""
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
