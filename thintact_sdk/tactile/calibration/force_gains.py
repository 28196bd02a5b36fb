"""Force calibration from presses of known load (``thintact calibrate-force``).

Input: a *press pack* ``.npz`` of membrane images on the profile's scene grid, ``f0``
(``N × M × 3``, no contact) and ``imgs`` (``P × N × M × 3``), float display units in [0, 1]
or uint8; and a *loads file* (JSON) ``{"loads_n": [...]}`` with one entry per press: the
normal load F_z in newtons, or ``[F_x, F_y, F_z]`` (the force the object applies to the
membrane, x with columns, y with rows, z into the gel).

Every press is interpreted as a sensor would (the device's LUT, markers tracked from
``f0``) and the gains of :class:`~thintact_sdk.tactile.interpretation.force.ForceModel` are fitted:

* normal: when the presses' fill ratios φ spread over at least :data:`FILL_SPREAD` (several
  indenter shapes), c_0 and c_1 by least squares; otherwise (one indenter shape) one scale
  of the shipped shape constants, which is what a gel's unknown modulus changes
  (F_z ∝ E* for a given shape);
* shear: c_t on the presses whose tangential load exceeds :data:`SHEARED_SHARE` of F_z
  (the shipped c_t kept, and said so, when there is none).

The gains are stored beside the device's tactile LUT, ``<device>/tactile/force.json``
(:func:`thintact_sdk.tactile.calibration.store.force_calibration_path`), with the gel's E and ν they
were fitted with and the per-press report; :meth:`ForceModel.from_profile` reads them.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats import safe_json
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.safe_arrays import read_npz
from thintact_sdk.tactile.interpretation.force import (
    FORMAT,
    NORMAL_FILL_GAIN,
    NORMAL_GAIN,
    SHEAR_GAIN,
    ForceModel,
    fit_gain,
    fit_gains,
    loaded_core,
)
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT
from thintact_sdk.tactile.simulation.elastic import Elastomer

FILL_SPREAD = 0.1
"""Spread (max − min) of fill ratios above which c_0 and c_1 are fitted separately."""
SHEARED_SHARE = 0.1
"""A press counts as sheared when its tangential load exceeds this share of F_z."""


@dataclass
class ForceCalibration:
    """Fitted force gains and the per-press report.

    Attributes
    ----------
    normal_gain, normal_fill_gain, shear_gain
        c_0, c_1, c_t of :class:`ForceModel` (dimensionless).
    youngs_mpa, poisson
        The gel's E and ν the gains were fitted with (the profile's).
    normal_method, shear_method
        How each was fitted (``"c0+c1"``, ``"scale"``, ``"fitted"``, ``"shipped"``).
    rows
        Per press: ``press``, ``given_n`` [F_x, F_y, F_z] (F_x, F_y None when not given),
        ``estimated_n``, ``normal_error_n``, ``normal_error_rel``, ``shear_error_n``.
    """

    normal_gain: float
    normal_fill_gain: float
    shear_gain: float
    youngs_mpa: float
    poisson: float
    normal_method: str
    shear_method: str
    rows: list[dict[str, Any]] = field(default_factory=list)

    def model(self) -> ForceModel:
        """The fitted :class:`ForceModel`."""
        return ForceModel(Elastomer(self.youngs_mpa, self.poisson), self.normal_gain,
                          self.normal_fill_gain, self.shear_gain)

    def normal_rms_rel(self) -> float:
        """RMS of the relative normal-force errors over the presses."""
        rel = [float(r["normal_error_rel"]) for r in self.rows]
        return float(np.sqrt(np.mean(np.square(rel)))) if rel else float("nan")

    def to_json(self) -> dict[str, Any]:
        """The stored form (``force.json``)."""
        return {
            "format": FORMAT,
            "force_normal_gain": self.normal_gain,
            "force_normal_fill_gain": self.normal_fill_gain,
            "force_shear_gain": self.shear_gain,
            "elastomer_youngs_mpa": self.youngs_mpa,
            "elastomer_poisson": self.poisson,
            "normal_method": self.normal_method,
            "shear_method": self.shear_method,
            "normal_rms_rel": self.normal_rms_rel(),
            "presses": self.rows,
        }

    def save(self, path: Path) -> Path:
        """Write :meth:`to_json` to ``path`` (its folder created); returns the path."""
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_json(), indent=1, allow_nan=False) + "\n")
        return path


def load_press_pack(path: Path, profile: Profile) -> tuple[np.ndarray, np.ndarray]:
    """``(f0, imgs)`` of a press pack as float32 display units, checked against the profile.

    Raises
    ------
    CalibrationError
        Naming the file and array: unreadable, a key missing, wrong shape, non-finite.
    """
    arrays = read_npz(path, what="press pack", error=CalibrationError, optional=("f0", "imgs"),
                      members=())  # header first: no pickle, no huge allocation
    for key in ("f0", "imgs"):
        if key not in arrays:
            raise CalibrationError(f"press pack {path}: no array {key!r} (needs f0 and imgs)")
    n, m = profile.scene.rows, profile.scene.cols
    f0, imgs = arrays["f0"], arrays["imgs"]
    if f0.shape != (n, m, 3):
        raise CalibrationError(f"press pack {path}: f0 has shape {f0.shape}, expected "
                               f"{(n, m, 3)} (the profile's scene grid)")
    if imgs.ndim != 4 or imgs.shape[1:] != (n, m, 3) or len(imgs) == 0:
        raise CalibrationError(f"press pack {path}: imgs has shape {imgs.shape}, expected "
                               f"(P, {n}, {m}, 3) with P >= 1")
    out = []
    for key, a in (("f0", f0), ("imgs", imgs)):
        if a.dtype == np.uint8:
            a = a.astype(np.float32) / np.float32(255.0)
        elif a.dtype.kind != "f":
            raise CalibrationError(f"press pack {path}: {key} is {a.dtype}, expected float "
                                   "display units or uint8")
        if not np.isfinite(a).all():
            raise CalibrationError(f"press pack {path}: {key} has non-finite values")
        out.append(np.asarray(a, np.float32))
    return out[0], out[1]


def load_loads(path: Path, presses: int) -> np.ndarray:
    """``P × 3`` loads [F_x, F_y, F_z] in N (F_x, F_y NaN where only F_z was given).

    Raises
    ------
    CalibrationError
        Naming the file and entry: not JSON, no ``loads_n`` list, a count other than the
        presses', an entry that is not a number or three numbers, F_z not positive.
    """
    try:
        data = safe_json.loads(path.read_text(), f"loads file {path}", CalibrationError)
    except (OSError, UnicodeDecodeError) as err:
        raise CalibrationError(f"loads file {path}: not readable JSON ({err})") from None
    items = data.get("loads_n") if isinstance(data, dict) else None
    if not isinstance(items, list):
        raise CalibrationError(f"loads file {path}: needs a list 'loads_n' (one load per press)")
    if len(items) != presses:
        raise CalibrationError(f"loads file {path}: {len(items)} loads for {presses} presses")
    out = np.full((presses, 3), np.nan)

    def number(v: Any) -> bool:
        return not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v)

    for i, item in enumerate(items):
        if number(item):
            out[i, 2] = float(item)
        elif isinstance(item, list) and len(item) == 3 and all(number(v) for v in item):
            out[i] = [float(v) for v in item]
        else:
            raise CalibrationError(f"loads file {path}: loads_n[{i}] is {item!r}; expected F_z "
                                   "in N or [F_x, F_y, F_z]")
        if out[i, 2] <= 0:
            raise CalibrationError(f"loads file {path}: loads_n[{i}] has F_z {out[i, 2]:g} N; "
                                   "a press needs a positive normal load")
    return out


def calibrate_force(profile: Profile, lut: PhotometricLUT, f0: np.ndarray, imgs: np.ndarray,
                    loads_n: np.ndarray) -> ForceCalibration:
    """Fit the force gains on presses of known load (see the module docstring).

    Parameters
    ----------
    profile, lut
        The device and its photometric LUT.
    f0, imgs
        ``N × M × 3`` no-contact image and ``P × N × M × 3`` presses (display units).
    loads_n
        ``P × 3`` known loads (:func:`load_loads`).

    Raises
    ------
    CalibrationError
        A press without contact (named by index), or too few presses for the fit.
    """
    from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter

    interp = TactileInterpreter(profile, lut)
    el = Elastomer.from_profile(profile)
    unit = ForceModel(el, 0.0, 0.0, 1.0)
    p = interp.params
    normal_feats, fills, unit_shear = [], [], []
    for i, img in enumerate(imgs):
        interp.set_reference(f0)
        frame = interp.interpret(img, 0, i + 1)
        core = loaded_core(frame.depth_mm, p.mm_per_px, p.contact_threshold_mm)
        if core is None or core.radius_mm <= 0:
            raise CalibrationError(f"press {i} shows no contact (peak depth "
                                   f"{float(np.max(frame.depth_mm)):.3f} mm); remove it or "
                                   "check f0 is the unloaded membrane")
        normal_feats.append(unit.normal_features(core))
        fills.append(core.fill)
        unit_shear.append(unit.estimate(frame.depth_mm, p.mm_per_px, p.contact_threshold_mm,
                                        interp.tracker.reference_mm,
                                        frame.marker_displacements_mm)[:2])
    feats = np.array(normal_feats)
    fz = loads_n[:, 2]
    if len(imgs) >= 3 and float(np.ptp(fills)) >= FILL_SPREAD:
        c0, c1 = (float(v) for v in fit_gains(feats, fz))
        normal_method = "c0+c1"
    else:
        shape = feats @ np.array([NORMAL_GAIN, NORMAL_FILL_GAIN])
        scale = fit_gain(shape, fz)
        c0, c1 = scale * NORMAL_GAIN, scale * NORMAL_FILL_GAIN
        normal_method = "scale"
    shear_given = np.hypot(loads_n[:, 0], loads_n[:, 1])
    shear_unit = np.array([float(np.hypot(*s)) for s in unit_shear])
    sheared = np.isfinite(shear_given) & (shear_given > SHEARED_SHARE * fz) & np.isfinite(shear_unit)
    if sheared.any():
        ct, shear_method = fit_gain(shear_unit[sheared], shear_given[sheared]), "fitted"
    else:
        ct, shear_method = SHEAR_GAIN, "shipped"
    cal = ForceCalibration(c0, c1, float(ct), el.youngs_mpa, el.poisson, normal_method,
                           shear_method)
    for i in range(len(imgs)):
        est_z = max(0.0, c0 * feats[i, 0] + c1 * feats[i, 1])
        est_xy = ct * np.asarray(unit_shear[i], np.float64)
        given = [None if not np.isfinite(v) else float(v) for v in loads_n[i]]
        shear_err = (None if given[0] is None or not np.isfinite(est_xy).all()
                     else float(np.hypot(*(est_xy - loads_n[i, :2]))))
        cal.rows.append({
            "press": i,
            "given_n": given,
            "estimated_n": [None if not np.isfinite(v) else float(v) for v in est_xy] + [est_z],
            "normal_error_n": est_z - float(fz[i]),
            "normal_error_rel": (est_z - float(fz[i])) / float(fz[i]),
            "shear_error_n": shear_err,
        })
    return cal
