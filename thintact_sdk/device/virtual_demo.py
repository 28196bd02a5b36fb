"""A ball press on a virtual sensor, end to end: the library behind ``thintact demo``.

:func:`run_demo` lays a simulated ball press (with a little shear) on the membrane of a
profile whose camera renders the simulator's world; the sensor reads the no-contact
reference, then the press, and bins, reconstructs and interprets the raw frame exactly as it
would a real camera's. :class:`DemoResult` holds the arrays and the figures of merit
(``summary``, the command's ``demo.json``); the figure is
:func:`thintact_sdk.apps.viewer.demo_figure.demo_figure`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from thintact_sdk.device.cameras import camera_is_simulated
from thintact_sdk.device.virtual_bench import get_scene_slot
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.frames import TactileFrame

__all__ = ["DEPTH_RANGE_MM", "DemoResult", "run_demo"]

DEPTH_RANGE_MM = (0.05, 2.0)
"""Accepted indentation depths of the demo's ball, mm (inclusive)."""


@dataclass(frozen=True)
class DemoResult:
    """What :func:`run_demo` produced.

    Attributes
    ----------
    raw
        The raw Bayer frame of the press, ``H×W`` DN.
    signal
        The binned measurement above black, ``R×S×3`` DN (not a picture).
    frame
        The tactile frame the sensor made of ``raw``.
    press
        The simulated press (``scene`` N×M×3 display units, ``depth_mm`` N×M mm, its markers).
    scale
        Factor ball, place and shear were scaled by to fit the field (1 on a finger-sized one).
    depth_mm
        The indentation depth used, mm (the asked one, capped on a scaled-down field).
    contact_threshold_mm
        The profile's contact threshold (0.1 mm without a tactile section).
    summary
        The figures of merit (``demo.json``): ``profile``, ``psnr_db``, ``ssim``,
        ``depth_max_mm`` {estimated, true}, ``depth_rms_error_mm``,
        ``depth_rms_error_in_contact_mm`` (None when the truth never reaches the threshold),
        ``contact``, ``contact_area_mm2``, ``markers_tracked``,
        ``marker_displacement_rms_error_mm`` (NaN with no tracked marker),
        ``raw_to_tactile_latency_ms`` (wall time of ``Sensor.process``).
    """

    raw: np.ndarray
    signal: np.ndarray
    frame: TactileFrame
    press: Any
    scale: float
    depth_mm: float
    contact_threshold_mm: float
    summary: dict[str, Any]


def run_demo(profile: Profile, depth_mm: float = 0.75, radius_mm: float = 2.0,
             shear_mm: tuple[float, float] = (0.12, -0.06)) -> DemoResult:
    """Press a ``radius_mm`` ball ``depth_mm`` deep (sheared by ``shear_mm`` x, y) into the
    membrane of ``profile``'s virtual sensor and measure what the sensor makes of it, as
    ``thintact demo`` does. On a field smaller than a finger the ball, its place and the shear
    are scaled down whole (:func:`~thintact_sdk.tactile.calibration.ball_press.ball_radius_for_field`).

    Raises
    ------
    ThinTactError
        A profile whose camera does not render the simulator's world, or ``depth_mm``
        outside :data:`DEPTH_RANGE_MM` (named as ``--depth-mm``).
    """
    from thintact_sdk.device.cameras import to_measurement
    from thintact_sdk.device.sensor import Sensor
    from thintact_sdk.reconstruction.metrics import psnr, ssim
    from thintact_sdk.tactile import Sphere, TactileSimulator
    from thintact_sdk.tactile.calibration.ball_press import ball_radius_for_field
    from thintact_sdk.tactile.calibration.evaluation import depth_rms as depth_rms_in_contact
    from thintact_sdk.tactile.calibration.evaluation import marker_errors

    if not camera_is_simulated(profile):
        raise ThinTactError(
            f"the demo needs a profile whose camera is the virtual sensor; {profile.name!r} uses "
            f"{profile.camera.plugin if profile.camera else 'no camera'} (try --profile virtual-finger)"
        )
    if not DEPTH_RANGE_MM[0] <= depth_mm <= DEPTH_RANGE_MM[1]:
        raise ThinTactError(f"--depth-mm must be between {DEPTH_RANGE_MM[0]} and {DEPTH_RANGE_MM[1]} mm")
    sim = TactileSimulator.for_profile(profile)
    flat = sim.flat()
    # the press is laid out for a finger-sized field; a smaller field gets it scaled down whole
    scale = ball_radius_for_field(profile, radius_mm) / radius_mm
    depth = depth_mm if scale == 1 else min(depth_mm, 0.75 * scale * radius_mm)
    press = sim.press(Sphere(scale * radius_mm), depth, center_mm=(scale * 1.2, scale * -0.8),
                      shear_mm=(scale * shear_mm[0], scale * shear_mm[1]))
    slot = get_scene_slot(profile.name)  # the slot the simulated camera renders (keyed by profile name)
    with Sensor(profile, camera_settings={"fps": 0}) as sensor:
        slot.set(flat.scene)
        sensor.read()  # the first frame is the no-contact reference
        slot.set(press.scene)
        raw = sensor.read_raw()
        t0 = time.perf_counter()
        frame = sensor.process(raw)
        latency_ms = (time.perf_counter() - t0) * 1e3
        interpreter = sensor.interpreter
    slot.set(None)

    meas = to_measurement(raw, profile)
    truth_depth = press.depth_mm
    depth_rms = float(np.sqrt(np.mean((frame.depth_mm - truth_depth) ** 2)))
    threshold = profile.tactile.contact_threshold_mm if profile.tactile else 0.1
    contact_rms = depth_rms_in_contact(frame.depth_mm, truth_depth, threshold)
    errors, tracked = marker_errors(interpreter, frame.marker_displacements_mm, press)
    marker_rms = float(np.sqrt(np.mean(errors**2))) if tracked else float("nan")
    summary: dict[str, Any] = {
        "profile": profile.name,
        "psnr_db": psnr(np.clip(frame.image, 0, 1), press.scene),
        "ssim": ssim(np.clip(frame.image, 0, 1), press.scene),
        "depth_max_mm": {"estimated": float(frame.depth_mm.max()), "true": float(truth_depth.max())},
        "depth_rms_error_mm": depth_rms,
        "depth_rms_error_in_contact_mm": contact_rms if np.isfinite(contact_rms) else None,
        "contact": bool(frame.contact),
        "contact_area_mm2": float(frame.contact_area_mm2),
        "markers_tracked": tracked,
        "marker_displacement_rms_error_mm": marker_rms,
        "raw_to_tactile_latency_ms": latency_ms,
    }
    return DemoResult(raw.data, meas.signal(), frame, press, scale, depth, float(threshold), summary)
