"""Frame types flowing through the SDK: raw → measurement → (scene) → tactile.

Array conventions: images are ``rows × cols × channels`` numpy arrays, channel order
R, G, B. Times are nanoseconds (monotonic host clock unless stated otherwise).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class RawFrame:
    """One frame as the camera delivers it, before Bayer binning.

    Attributes
    ----------
    data
        ``H × W`` (Bayer mosaic or mono) or ``H × W × C`` array, integer DN.
    timestamp_ns
        Host monotonic time at which the frame was received.
    frame_id
        The camera's frame counter (gaps mean dropped frames).
    pixel_format
        GenICam-style pixel format name, e.g. ``"BayerRG12"``, ``"Mono8"``, ``"RGB8"``.
    exposure_us, gain_db
        Exposure time and analogue gain when the frame was taken (``None`` if unknown).
    device_timestamp_ns
        The device's own timestamp when it reports one.
    meta
        Anything else the backend knows (e.g. ``{"dropped_before": 2}``).
    """

    data: np.ndarray
    timestamp_ns: int
    frame_id: int
    pixel_format: str = "BayerRG12"
    exposure_us: float | None = None
    gain_db: float | None = None
    device_timestamp_ns: int | None = None
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass
class Measurement:
    """A binned measurement image (paper §IV: R, mean of the two G, B).

    Attributes
    ----------
    data
        ``R × S × 3`` float32, digital numbers with the black level *not* removed
        (as in recordings, CONTRACTS §3).
    black_level_dn
        Black level of the sensor in DN.
    timestamp_ns, frame_id, exposure_us
        Copied from the raw frame.
    sensor_bin
        ``b``: ``data`` holds the ``b × b`` block means of the profile's ``R × S`` measurement,
        ``R/b × S/b × C`` (made for a decoder declaring ``input = "binned"``, :class:`~thintact_sdk.interfaces.Decoder`,
        see :func:`thintact_sdk.device.cameras.to_measurement`); 1 for the measurement itself.
    """

    data: np.ndarray
    black_level_dn: float
    timestamp_ns: int = 0
    frame_id: int = 0
    exposure_us: float | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    sensor_bin: int = 1

    def signal(self) -> np.ndarray:
        """``R × S × 3`` float32 signal in DN above black level."""
        return self.data.astype(np.float32) - np.float32(self.black_level_dn)


@dataclass
class TactileFrame:
    """What robot programs read: the reconstructed image and the contact interpretation.

    Attributes
    ----------
    image
        ``N × M × 3`` float32 reconstructed scene, display units (≈ [0, 1]).
    depth_mm
        ``N × M`` float32 indentation depth in mm (positive into the elastomer).
    marker_positions_mm
        ``K × 2`` float32 current marker centres (x, y) in mm, NaN where lost.
    marker_displacements_mm
        ``K × 2`` float32 displacement of each marker from the reference frame in mm.
    contact
        True when the contact region covers at least the interpreter's smallest contact
        area (0.1 mm² by default); there is none without a pixel deeper than the profile's
        contact threshold.
    contact_area_mm2
        Area of the contact region in mm²: where the membrane wraps the object (concave
        depth, holes filled), not the skirt a real gel sinks in around it
        (:mod:`thintact_sdk.tactile.interpretation.contact_region`).
    shear_direction_rad
        Direction of the mean marker displacement (atan2(y, x)), NaN without shear.
    shear_mm
        ``(2,)`` float64 mean (dx, dy) displacement in mm of the markers that move (lost
        markers ignored); (0, 0) when none moves. Always finite.
    timestamp_ns, frame_id
        Of the raw frame this was computed from.
    force_n
        ``(3,)`` float64 force the object applies to the membrane, newtons [F_x, F_y, F_z]
        (x with columns, y with rows, z into the elastomer), from the linear elastic model
        of :mod:`thintact_sdk.tactile.interpretation.force`; zeros without contact, F_x/F_y NaN when no
        marker is in the contact. None where not computed.
    slip_ratio
        Share of the loaded contact that slips, in [0, 1] (0 stuck, 1 sliding;
        :mod:`thintact_sdk.tactile.interpretation.slip`); None without contact or where not computed.
    """

    image: np.ndarray
    depth_mm: np.ndarray
    marker_positions_mm: np.ndarray
    marker_displacements_mm: np.ndarray
    contact: bool
    contact_area_mm2: float
    timestamp_ns: int
    frame_id: int
    shear_direction_rad: float = float("nan")
    shear_mm: np.ndarray = field(default_factory=lambda: np.zeros(2))
    latency_ms: float | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    force_n: np.ndarray | None = None
    slip_ratio: float | None = None
