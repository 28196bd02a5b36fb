"""Diagnosing a large recording on sensor-binned data (the paper's 1024×1280 device).

Binning the sensor ``b × b`` is exact for the imaging model: a sensor pixel integrates the
irradiance over its square (CONTRACTS §4), so the mean of a ``b × b`` block of pixels is the
pixel of a device whose sensor has ``b``-times the pitch and ``1/b`` the rows and columns,
with the same scene, mask and geometry. Every kernel-stage effect (mask shift, leakage,
angular response, geometry, diffraction, ...) and every linear signal- or DN-stage effect
(colour crosstalk, veiling glare, stray light, gain) commutes with it. A nonlinear DN effect
(sensor gamma, a clip level) and a sensor blur narrower than a block are binned after they
act, so on binned data they are fitted as the nearest binned model (their fit is an
approximation of order the signal's variation inside a block).

The noise of the mean of ``b²`` independent pixels is the single pixel's variance over
``b²``; :func:`binned_variance_fn` gives the diagnosis that variance, so χ² keeps its
meaning (CONTRACTS §6) on the binned data. A block with a saturated pixel is marked saturated
(its mean is not the model's mean of unclipped values).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData
from thintact_sdk.diagnosis.imaging.stats import VarianceFn, default_variance_fn
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import NoiseSpec, Profile, profile_from_dict

if TYPE_CHECKING:
    from thintact_sdk.diagnosis.imaging.forward_model import Values

MAX_DIAGNOSIS_PIXELS = 160 * 128
"""Sensor pixels (per frame and channel) above which ``thintact diagnose`` bins the sensor:
the size its effect screening and fits are measured at (``docs/diagnosis.md``)."""


def auto_bin_factor(rows: int, cols: int, max_pixels: int = MAX_DIAGNOSIS_PIXELS) -> int:
    """The smallest factor ``b`` dividing both ``rows`` and ``cols`` with
    ``(rows/b)·(cols/b) ≤ max_pixels`` (1 when the sensor is small enough already).

    Raises
    ------
    ThinTactError
        When no common divisor brings the sensor under ``max_pixels``.
    """
    if rows * cols <= max_pixels:
        return 1
    g = math.gcd(rows, cols)
    for b in range(2, g + 1):
        if g % b == 0 and (rows // b) * (cols // b) <= max_pixels:
            return b
    raise ThinTactError(
        f"sensor {rows}×{cols}: no common bin factor of rows and cols brings it under "
        f"{max_pixels} pixels for the diagnosis; pass --bin explicitly"
    )


def binned_profile(profile: Profile, b: int) -> Profile:
    """The device whose sensor pixels are ``b × b`` blocks of ``profile``'s (pitch × b; the
    sensor section's ``block_pixels`` says so, for effects defined between single pixels)."""
    if b < 1 or profile.sensor.rows % b or profile.sensor.cols % b:
        raise ThinTactError(
            f"bin factor {b} must divide the sensor's rows ({profile.sensor.rows}) and "
            f"cols ({profile.sensor.cols})"
        )
    d = profile.contract_dict()
    d["name"] = f"{profile.name}-bin{b}"
    d["sensor"]["rows"] = profile.sensor.rows // b
    d["sensor"]["cols"] = profile.sensor.cols // b
    d["sensor"]["pixel_pitch_um"] = profile.sensor.pixel_pitch_um * b
    # effects defined between the recording's pixels (the sampled sensor blur) take their
    # weights there and sum them over the blocks
    d["sensor"]["block_pixels"] = b * int(getattr(profile.sensor, "block_pixels", None) or 1)
    return profile_from_dict(d)


def bin_frames(measured_dn: np.ndarray, b: int, saturation_dn: float) -> np.ndarray:
    """``F × R × S × C`` DN → ``F × R/b × S/b × C`` block means; a block holding a pixel at
    or above ``saturation_dn - 0.5`` reads ``saturation_dn`` (so it is left out of χ²)."""
    f, r, s, c = measured_dn.shape
    blocks = measured_dn.reshape(f, r // b, b, s // b, b, c)
    out = blocks.mean(axis=(2, 4))
    sat = (blocks >= saturation_dn - 0.5).any(axis=(2, 4))
    out[sat] = saturation_dn
    return out


def bin_data(data: DiagnosisData, b: int) -> DiagnosisData:
    """The recording's frames with the sensor binned ``b × b`` (scenes unchanged)."""
    if b == 1:
        return data
    prof = binned_profile(data.profile, b)
    meas = bin_frames(data.measured_dn, b, float(data.profile.noise.saturation_dn))
    return DiagnosisData(prof, list(data.labels), data.scenes, meas, data.skipped)


def binned_variance_fn(b: int, base: VarianceFn | None = None) -> VarianceFn:
    """The noise variance of a ``b × b`` block mean: the pixel's variance over ``b²``."""
    inner = base or default_variance_fn()
    scale = 1.0 / float(b * b)

    def variance(pred_dn: np.ndarray, noise: NoiseSpec) -> np.ndarray:
        return inner(pred_dn, noise) * scale

    return variance


def unbin_hotspots(report: dict[str, Any], b: int) -> None:
    """Scale the hotspot rectangles of a CONTRACTS §6 report from binned to sensor pixels
    (in place)."""
    if b == 1:
        return
    for part in ("located", "unexplained"):
        for h in report.get(part, {}).get("hotspots", []):
            for k in ("row0", "row1", "col0", "col1"):
                h[k] = int(h[k]) * b


DIAGNOSIS_FAMILY_BYTES = 256 * 1024**2
"""Largest one-axis kernel family a candidate may need for the diagnosis to screen it: the
fit builds tens of kernels, each taking time in proportion to its family's bytes."""

PROBES: dict[str, tuple[dict[str, dict[str, float]], tuple[str, ...]]] = {
    "mask_misalignment": ({"mask_misalignment": {"angle_deg": 0.3, "dx_um": 0.0, "dy_um": 0.0}},
                          ("angle_deg",)),
    "refraction": ({"refraction": {"n_scene_side": 1.41}}, ("n_scene_side",)),
}
"""Per family-building candidate: the physics at which its kernel size is estimated (the
first step of its fit is of this order) and the fit parameters that need the family (held
at their null value when it is too large; the others are still screened: a mask *shift*
keeps the plain separable kernel, only the angle needs the rotated family)."""


@dataclass(frozen=True)
class ScreeningLimits:
    """What the diagnosis cannot screen on a device, and why (:func:`screening_limits`).

    Attributes
    ----------
    held
        ``{effect: fit-parameter labels}`` held at their null value
        (:attr:`~thintact_sdk.diagnosis.imaging.engine.DiagnoseOptions.held_params`).
    dropped
        Effects with every fit parameter held: not tried at all.
    not_screened
        ``{"effect" or "effect.param": reason}`` for ``report.json`` ``binned.not_screened``
        (a whole effect when dropped, else each held parameter).
    """

    held: dict[str, tuple[str, ...]] = field(default_factory=dict)
    dropped: tuple[str, ...] = ()
    not_screened: dict[str, str] = field(default_factory=dict)


def screening_limits(profile: Profile, limit_bytes: float | None = None) -> ScreeningLimits:
    """The fit parameters whose kernels need tabulated families above ``limit_bytes`` on
    this device: the rotated mask's displacement family and refraction's ``D²`` family grow
    with the sensor's and the scene's extent, not with binning alone. (The simulator can still
    build a wide device's refraction block by block for ``simulate``, but a fit rebuilds the
    kernel at every step, so the diagnosis holds it instead.) Their parameters are
    held at the null value; the rest of the effect (a mask shift) is still screened
    (``limit_bytes`` default: :data:`DIAGNOSIS_FAMILY_BYTES`)."""
    from thintact_sdk.diagnosis.imaging.candidates import CANDIDATES
    from thintact_sdk.simulation import refracted as sim_refracted
    from thintact_sdk.simulation import rotated as sim_rotated
    from thintact_sdk.simulation.effects import resolve_physics
    from thintact_sdk.simulation.params import kernel_params
    from thintact_sdk.simulation.simulator import _expansion

    limit = DIAGNOSIS_FAMILY_BYTES if limit_bytes is None else float(limit_bytes)
    held: dict[str, tuple[str, ...]] = {}
    dropped: list[str] = []
    why: dict[str, str] = {}
    for name, (probe, params) in PROBES.items():
        if name in profile.physics:
            continue
        phys = resolve_physics({**dict(profile.physics), **probe})
        kp = kernel_params(profile, phys)
        if name == "mask_misalignment":
            size = sim_rotated.rotated_family_bytes(kp, _expansion(kp).rank)
        else:
            size = sim_refracted.refracted_family_bytes(kp)
        if size <= limit:
            continue
        reason = (f"its kernel family at {probe[name]} would be {size / 1024**2:.0f} MiB "
                  f"on the {profile.sensor.rows}×{profile.sensor.cols} → "
                  f"{profile.scene.rows}×{profile.scene.cols} device (limit "
                  f"{limit / 1024**2:.0f} MiB)")
        labels = CANDIDATES[name].labels if name in CANDIDATES else params
        held[name] = params
        if set(params) >= set(labels):
            dropped.append(name)
            why[name] = reason
            continue
        rest = ", ".join(lab for lab in labels if lab not in params)
        for p in params:
            null = CANDIDATES[name].null(profile)[labels.index(p)]
            why[f"{name}.{p}"] = f"held at {null:g} ({rest} screened): {reason}"
    return ScreeningLimits(held, tuple(dropped), why)


FINE_AMPLITUDE_FRAMES = 4
"""Frames of the unbinned recording on which :func:`unbinned_amplitude_fn` measures an
effect's change (spread over the recording; each costs a full-size simulation)."""


def unbinned_amplitude_fn(data: DiagnosisData, n_frames: int = FINE_AMPLITUDE_FRAMES,
                          sys_frac: float = 1e-3) -> Callable[[Values, Values], float]:
    """``(values before, values after) -> rms change of the prediction / rms signal`` on
    ``n_frames`` frames of the **unbinned** recording ``data`` (gains solved there for each;
    float32 products, simulations cached), for
    :attr:`~thintact_sdk.diagnosis.imaging.engine.DiagnoseOptions.fine_amplitude`.

    Binning averages away structure finer than a block: a 7 um mask shift of the paper's
    device changes its 8×8-binned prediction by 4e-4 of the signal but is clearly above the
    diagnosis's amplitude floor (6e-4, the simulator's own accuracy) on the unbinned one.
    """
    from thintact_sdk.diagnosis.imaging.forward_model import DiagnosisModel
    from thintact_sdk.diagnosis.imaging.recording_data import subset_frames

    made: list[DiagnosisModel] = []  # built at the first call (most runs never need it)

    def amplitude(before: Values, after: Values) -> float:
        if not made:
            made.append(DiagnosisModel(subset_frames(data, n_frames), simulate_float32,
                                       default_variance_fn(), sys_frac=sys_frac, cache_size=2))
        model = made[0]
        p0 = model.evaluate(before).pred_dn
        p1 = model.evaluate(after).pred_dn
        m = model.fit_mask
        sig = float(np.sqrt(np.mean((p0[m] - model.black) ** 2)))
        return float(np.sqrt(np.mean((p1[m] - p0[m]) ** 2))) / max(sig, 1e-12)

    return amplitude


def simulate_float32(profile: Profile, scenes: np.ndarray) -> np.ndarray:
    """The project simulator in float32 products (relative error ~1e-7, about twice as fast
    at full size), float64 out."""
    from thintact_sdk.simulation.simulator import Simulator

    return np.asarray(Simulator(profile, precision="float32").forward_batch(scenes), np.float64)


def full_size_check(data: DiagnosisData, final_values: dict[str, np.ndarray],
                    sys_frac: float = 1e-3) -> dict[str, float]:
    """The fitted model evaluated on the unbinned recording.

    The effects are named and fitted on binned data; this evaluates the outcome at full
    resolution once (gains and closed-form terms refitted there, the effects' parameters as
    fitted): ``{"rms_dn", "chi2_per_dof"}``, CONTRACTS §6 χ² over every unbinned,
    unsaturated pixel. Structure finer than a block that the binned fit missed shows up
    here as χ²/dof above 1. (One evaluation: at the paper's size each one is the costliest
    step of a run, in time and in peak memory.)
    """
    from thintact_sdk.diagnosis.imaging.forward_model import full_size_stats

    st = full_size_stats(data, final_values, simulate_float32, sys_frac)
    return {"rms_dn": round(st.rms_dn, 4), "chi2_per_dof": round(st.chi2_per_dof, 4)}
