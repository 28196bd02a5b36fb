"""Raw camera frames → measurements: the one path every camera goes through.

Every consumer of camera frames (the ``Sensor`` robot API, ``thintact record``, the
calibration wizard) turns :class:`~thintact_sdk.frames.RawFrame` objects into
:class:`~thintact_sdk.frames.Measurement` objects here, so Bayer binning
(:func:`thintact_sdk.pixels.bayer.bin_bayer`) and the black level are applied one way only.

Typical use::

    from thintact_sdk.device.cameras import open_camera, to_measurement
    with open_camera(profile) as cam:
        m = to_measurement(cam.read(), profile)     # R × S × 3 float32 DN

:class:`FrameGapCounter` keeps count of dropped frames from gaps in the camera's frame ids.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_sdk.device.registry import PluginRegistry, get_registry
from thintact_sdk.errors import (
    DeviceError,
    InvalidShapeError,
    InvalidValueError,
    PluginError,
    ProfileError,
)
from thintact_sdk.formats.profiles import BAYER_PLANES, Profile
from thintact_sdk.frames import Measurement, RawFrame
from thintact_sdk.interfaces import Camera
from thintact_sdk.pixels.bayer import bin_bayer, block_mean, pattern_from_pixel_format, split_bayer
from thintact_sdk.pixels.tone_curve import linearize

__all__ = [
    "DroppedFramesWarning",
    "FrameGapCounter",
    "binning_pattern",
    "bit_depth_problem",
    "channel_layout",
    "create_camera",
    "open_camera",
    "pixel_format_bits",
    "read_measurement",
    "to_measurement",
]


class DroppedFramesWarning(UserWarning):
    """Issued when gaps in the camera's frame ids show that frames were lost."""


def binning_pattern(raw: RawFrame, profile: Profile) -> str:
    """The CFA layout used to bin ``raw``.

    Parameters
    ----------
    raw
        The frame; its ``pixel_format`` wins when it names a Bayer layout (``BayerRG12`` →
        ``RGGB``), since the camera knows its own readout (ROI offsets can change it).
    profile
        Supplies ``camera.bayer_pattern`` for mono-coded mosaics (a raw mosaic delivered as
        ``Mono8``/``Mono16``) and ``none`` for already binned RGB frames.

    Returns
    -------
    str
        ``RGGB``, ``BGGR``, ``GRBG``, ``GBRG`` or ``none`` (``H × W × 3`` pass-through).
    """
    if raw.data.ndim == 3:
        return "none"
    from_format = pattern_from_pixel_format(raw.pixel_format)
    if from_format is not None:
        return from_format
    declared = profile.camera.bayer_pattern if profile.camera is not None else "RGGB"
    if declared == "none":
        raise DeviceError(
            f"the camera delivers a 2-D {raw.pixel_format} frame but profile {profile.name!r} "
            "declares camera.bayer_pattern 'none' (an already binned RGB frame); set the CFA "
            "layout (RGGB, BGGR, GRBG, GBRG)"
        )
    return declared


def channel_layout(profile: Profile) -> str:
    """How raw frames become the profile's channels: ``binned`` (R, mean G, B),
    ``planes`` (R, Gr, Gb, B kept apart) or ``mono`` (one channel, no Bayer filter)."""
    channels = list(profile.sensor.channels)
    if channels == BAYER_PLANES:
        return "planes"
    return "mono" if channels == ["mono"] else "binned"


def _bin(data: np.ndarray, pattern: str, layout: str, out: np.ndarray | None, block: int = 1) -> np.ndarray:
    """The frame in the profile's channel layout (float32 DN), ``block × block`` means of it."""
    if layout == "mono":
        if data.ndim != 2:
            raise InvalidShapeError(f"a monochrome sensor delivers 2-D frames, got shape {data.shape}")
        if block != 1:
            return block_mean(data[..., None], block, out)
        return data.astype(np.float32, copy=False)[..., None]
    if layout == "planes":
        return split_bayer(data, pattern, out=out, block=block)
    return bin_bayer(data, pattern, out=out if pattern != "none" or block != 1 else None, block=block)


def pixel_format_bits(pixel_format: str) -> int | None:
    """Bits per sample named by a GenICam pixel format (``BayerRG12p`` → 12), or None."""
    digits = re.search(r"(\d+)(?:p|Packed|_?Planar)?f?$", pixel_format)
    return int(digits.group(1)) if digits else None


def bit_depth_problem(pixel_format: str, profile: Profile) -> str | None:
    """A message when the format cannot reach the profile's ``noise.saturation_dn``.

    E.g. a camera set to ``BayerRG8`` (at most 255 DN) under a profile calibrated for a
    12-bit sensor (saturation 4095 DN): black level, noise and saturation would all be
    wrong by a factor of 16. Returns None when the depth is unknown or sufficient.
    """
    bits = pixel_format_bits(pixel_format)
    if bits is None or pixel_format.endswith("f"):
        return None
    full_scale = 2**bits - 1
    if profile.noise.saturation_dn > full_scale:
        return (
            f"pixel format {pixel_format} gives at most {full_scale} DN but profile "
            f"{profile.name!r} has noise.saturation_dn {profile.noise.saturation_dn:g} DN; "
            "choose a deeper pixel format or a profile for this bit depth"
        )
    return None


def to_measurement(
    raw: RawFrame, profile: Profile, out: np.ndarray | None = None, sensor_bin: int = 1
) -> Measurement:
    """Linearise and bin one raw frame into a measurement with the profile's black level.

    The profile's ``sensor.channels`` pick the layout (:func:`channel_layout`): R, mean G, B
    (the paper's), the four Bayer sites R, Gr, Gb, B kept apart (FlatCam's,
    :func:`thintact_sdk.pixels.bayer.split_bayer`), or one monochrome channel (an ``R × S`` frame,
    no binning).

    A tone curve declared in ``sensor.tone_curve`` is undone first
    (:func:`thintact_sdk.pixels.tone_curve.linearize`), before binning, so that the two green sites
    are averaged in linear light and every decoder sees linear DN.

    Parameters
    ----------
    raw
        ``2R × 2S`` Bayer mosaic (integer DN), ``R × S`` monochrome frame, or ``R × S × 3``
        (or ``× 4``, alpha dropped) RGB frame that is passed through unbinned.
    profile
        Supplies the expected sensor size ``R × S``, the CFA layout
        (``camera.bayer_pattern``) and ``noise.black_level_dn``.
    out
        Optional preallocated ``R × S × C`` float32 array for the binned data
        (``R/b × S/b × C`` with ``sensor_bin`` b).
    sensor_bin
        ``b`` > 1: return the ``b × b`` block means of the measurement instead
        (``Measurement.sensor_bin = b``), binned from the mosaic in one pass
        (:func:`thintact_sdk.pixels.bayer.bin_sites`: each pixel averages a ``2b × 2b`` cell per colour
        site), for a decoder that solves on the binned sensor
        (``input = "binned"``, :class:`~thintact_sdk.interfaces.Decoder`). The same numbers as binning
        the measurement afterwards, up to float32 rounding.

    Returns
    -------
    Measurement
        ``data`` ``R × S × C`` float32 linear DN with the black level *not* removed; timestamps,
        frame id and exposure copied from ``raw``; ``meta`` holds the raw frame's meta plus
        ``pixel_format``, ``gain_db``, ``device_timestamp_ns`` (and ``tone_curve``, the kind
        undone, when the profile declares one).

    Raises
    ------
    DeviceError
        When the frame's size does not give the profile's sensor size after binning, or it
        holds codes beyond the declared tone-curve table.
    InvalidValueError
        When ``sensor_bin`` is not a positive divisor of the profile's ``sensor.rows`` and
        ``sensor.cols``.
    """
    rows, cols = profile.sensor.rows, profile.sensor.cols
    if sensor_bin < 1 or rows % sensor_bin or cols % sensor_bin:
        raise InvalidValueError(f"sensor_bin {sensor_bin}: the {rows}×{cols} measurement of profile "
                                f"{profile.name!r} cannot be binned in {sensor_bin}×{sensor_bin} blocks")
    data = raw.data
    if data.ndim == 3 and data.shape[2] == 4:
        data = data[..., :3]
    tone = profile.sensor.tone_curve
    if tone is not None:
        try:
            data = linearize(data, profile, f"{raw.pixel_format} frame {raw.frame_id}")
        except ValueError as err:
            raise DeviceError(str(err)) from None
    layout = channel_layout(profile)
    pattern = "mono" if layout == "mono" else binning_pattern(raw, profile)
    if layout == "planes" and pattern == "none":
        raise DeviceError(
            f"profile {profile.name!r} keeps the Bayer sites apart (sensor.channels "
            f"{BAYER_PLANES}) but the camera delivers an already binned {raw.pixel_format} "
            f"frame of shape {data.shape}; deliver the raw mosaic"
        )
    try:
        binned = _bin(data, pattern, layout, out, sensor_bin)
    except ValueError as err:
        raise DeviceError(f"cannot bin the {raw.pixel_format} frame {raw.frame_id}: {err}") from None
    if pattern in ("none", "mono") and out is not None and sensor_bin == 1:
        out[...] = binned
        binned = out
    expected = (rows, cols)
    if binned.shape[:2] != (rows // sensor_bin, cols // sensor_bin):
        need = {"none": f"{expected[0]}×{expected[1]}×3 RGB frame",
                "mono": f"{expected[0]}×{expected[1]} monochrome frame"}.get(
            pattern, f"{2 * expected[0]}×{2 * expected[1]} mosaic")
        raise DeviceError(
            f"the camera delivers {data.shape[0]}×{data.shape[1]} {raw.pixel_format} frames, "
            f"binned to {binned.shape[0] * sensor_bin}×{binned.shape[1] * sensor_bin}, but profile {profile.name!r} "
            f"expects a {expected[0]}×{expected[1]} measurement (a {need}); set the camera's "
            "Width/Height (ROI) or fix sensor.rows/cols"
        )
    meta: dict[str, Any] = dict(raw.meta)
    meta.update(
        pixel_format=raw.pixel_format,
        gain_db=raw.gain_db,
        device_timestamp_ns=raw.device_timestamp_ns,
        bayer_pattern=pattern,
    )
    if tone is not None:
        meta["tone_curve"] = tone.kind
    return Measurement(
        data=binned,
        black_level_dn=float(profile.noise.black_level_dn),
        timestamp_ns=int(raw.timestamp_ns),
        frame_id=int(raw.frame_id),
        exposure_us=raw.exposure_us,
        meta=meta,
        sensor_bin=sensor_bin,
    )


def camera_is_simulated(profile: Profile, registry: PluginRegistry | None = None) -> bool:
    """Whether the profile's camera plugin declares the ``"simulated"`` trait (it renders the
    simulator's world, e.g. the virtual sensor); False without a camera or a known plugin."""
    if profile.camera is None:
        return False
    try:
        comp = (registry or get_registry()).get("camera", profile.camera.plugin)
    except PluginError:
        return False
    return "simulated" in comp.traits


def create_camera(
    profile: Profile,
    registry: PluginRegistry | None = None,
    settings: dict[str, Any] | None = None,
) -> Camera:
    """Build (not open) the camera named by ``profile.camera.plugin``.

    Parameters
    ----------
    profile
        Its ``camera`` section names the plugin and holds the settings.
    registry
        Plugin registry to use; the process-wide one by default.
    settings
        Overrides merged over ``profile.camera.settings``.

    Raises
    ------
    ProfileError
        When the profile has no ``camera`` section.
    PluginError
        When no camera plugin of that name is installed.
    """
    if profile.camera is None:
        raise ProfileError(
            f"profile {profile.name!r} has no 'camera' section; add camera.plugin "
            "(virtual, genicam, uvc or replay) and its settings"
        )
    reg = registry if registry is not None else get_registry()
    merged = dict(profile.camera.settings)
    if settings:
        merged.update(settings)
    camera = reg.create("camera", profile.camera.plugin, profile, merged)
    if not isinstance(camera, Camera):
        raise DeviceError(
            f"camera plugin {profile.camera.plugin!r} returned {type(camera).__name__}, "
            "not a thintact_sdk.interfaces.Camera"
        )
    return camera


def open_camera(
    profile: Profile,
    registry: PluginRegistry | None = None,
    settings: dict[str, Any] | None = None,
) -> Camera:
    """Build and open the profile's camera (see :func:`create_camera`); close it when done.

    The returned camera is open and usable as a context manager (``with open_camera(p) as c``).
    """
    camera = create_camera(profile, registry, settings)
    camera.open()
    return camera


def read_measurement(camera: Camera, profile: Profile, timeout_s: float = 2.0) -> Measurement:
    """Read one frame from an opened ``camera`` and bin it (:func:`to_measurement`).

    Raises
    ------
    DeviceTimeoutError, DeviceLostError
        As raised by the camera's ``read``.
    """
    return to_measurement(camera.read(timeout_s=timeout_s), profile)


@dataclass
class FrameGapCounter:
    """Counts frames lost between consecutive frame ids.

    Feed every frame's id to :meth:`update`; it returns how many frames went missing just
    before this one. A frame id that does not increase (a camera restart or counter
    wrap-around) resets the reference without counting a drop.

    Attributes
    ----------
    dropped
        Total frames lost so far.
    gaps
        ``(frame_id, missing_before)`` for every gap seen.
    warn
        Issue a :class:`DroppedFramesWarning` at each gap.
    """

    dropped: int = 0
    gaps: list[tuple[int, int]] = field(default_factory=list)
    warn: bool = False
    last_id: int | None = None
    frames: int = 0

    def update(self, frame_id: int) -> int:
        """Register ``frame_id``; returns the number of frames missing just before it."""
        missing = 0
        if self.last_id is not None and frame_id > self.last_id + 1:
            missing = frame_id - self.last_id - 1
            self.dropped += missing
            self.gaps.append((frame_id, missing))
            if self.warn:
                warnings.warn(
                    f"{missing} frame(s) dropped before frame id {frame_id} "
                    f"({self.dropped} in total)",
                    DroppedFramesWarning,
                    stacklevel=2,
                )
        self.last_id = frame_id
        self.frames += 1
        return missing
