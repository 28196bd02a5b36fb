"""Frame-level normal and shear force from the depth map and the marker displacements.

A linear elastic model of the elastomer (:mod:`thintact_sdk.tactile.simulation.elastic`) with two
dimensionless gains fitted on simulated presses whose forces the half-space solution gives
(:mod:`thintact_sdk.tactile.simulation.loaded_press`):

* normal: ``F_z = c_n · E* · V / a`` — E* = E/(1 − ν²), V the indentation volume (mm³,
  depth integrated over the contact), a = √(A/π) the radius of the loaded core (the
  region deeper than half the peak depth: for a ball, exactly Hertz's contact circle). The
  shape constant c_n depends on how the pressure is spread (a Hertzian ball gives
  16/(9π) ≈ 0.57, a flat punch 2/π ≈ 0.64), so it is taken linear in the contact's fill
  ratio φ = V / (A_touch · d_peak) (0.5 for a paraboloid cap, → 1 for a flat punch):
  ``c_n = c_0 + c_1 · φ``;
* shear: ``(F_x, F_y) = c_t · G · a · δ`` — G = E/(2(1 + ν)), δ the mean displacement
  (mm) of the markers in the loaded core; Mindlin's stuck circle gives c_t = 8/(2 − ν).

On a real unit E (or the gains) must be calibrated with presses of known load: the shape
constants c_n, c_t hold for any gel, E and ν do not (see docs/tactile.md).
Forces are those the object applies to the membrane, in newtons, in the scene frame
(x with columns, y with rows, z into the elastomer).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats import safe_json
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.tactile.simulation.elastic import Elastomer

NORMAL_GAIN = -0.373
"""c_0 of c_n = c_0 + c_1·φ, fitted on 12 simulated presses (balls, cylinder, prism;
``thintact bench tactile``)."""
NORMAL_FILL_GAIN = 1.488
"""c_1 of c_n = c_0 + c_1·φ, fitted on the same presses."""
FILL_RANGE = (0.5, 1.0)
"""Fill ratios φ the normal model is applied over (clamped)."""
SHEAR_GAIN = 5.84
"""c_t fitted on the same presses (docs/tactile.md, "Force and slip")."""


@dataclass(frozen=True)
class LoadedCore:
    """Where the membrane carries the load.

    Attributes
    ----------
    mask
        ``N × M`` bool: deeper than the contact threshold and than half the peak depth.
    radius_mm
        √(area/π) of ``mask`` (mm).
    volume_mm3
        Depth integrated over every pixel deeper than the contact threshold (mm³).
    fill
        ``volume / (touching area · peak depth)``: 0.5 for a paraboloid cap, → 1 for a
        flat punch.
    """

    mask: np.ndarray
    radius_mm: float
    volume_mm3: float
    fill: float


def loaded_core(depth_mm: np.ndarray, mm_per_px: float, threshold_mm: float) -> LoadedCore | None:
    """The loaded core of a depth map, or None without contact (peak below threshold)."""
    d = np.asarray(depth_mm, np.float64)
    peak = float(d.max()) if d.size else 0.0
    if peak <= threshold_mm:
        return None
    touching = d > threshold_mm
    mask = touching & (d >= 0.5 * peak)
    area = float(mask.sum()) * mm_per_px**2
    volume = float(d[touching].sum()) * mm_per_px**2
    fill = volume / (float(touching.sum()) * mm_per_px**2 * peak)
    return LoadedCore(mask, float(np.sqrt(area / np.pi)), volume, fill)


def markers_in(mask: np.ndarray, reference_mm: np.ndarray, mm_per_px: float) -> np.ndarray:
    """``K`` bool: markers whose reference centre (x, y mm, scene-centred) lies in ``mask``."""
    ref = np.asarray(reference_mm, np.float64).reshape(-1, 2)
    rows, cols = mask.shape
    c = np.rint(ref[:, 0] / mm_per_px + (cols - 1) / 2).astype(int)
    r = np.rint(ref[:, 1] / mm_per_px + (rows - 1) / 2).astype(int)
    ok = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
    out = np.zeros(len(ref), bool)
    out[ok] = mask[r[ok], c[ok]]
    return out


@dataclass(frozen=True)
class ForceModel:
    """Normal and shear force from a tactile frame's geometry.

    Attributes
    ----------
    elastomer
        Gel material (E, ν): calibrate E on a real unit.
    normal_gain, normal_fill_gain, shear_gain
        c_0, c_1 and c_t (dimensionless, see module docstring).
    """

    elastomer: Elastomer = Elastomer()
    normal_gain: float = NORMAL_GAIN
    normal_fill_gain: float = NORMAL_FILL_GAIN
    shear_gain: float = SHEAR_GAIN

    @classmethod
    def from_profile(cls, profile: Profile) -> ForceModel:
        """Material from ``tactile.elastomer_*``; each gain from the profile's
        ``tactile.force_normal_gain``, ``force_normal_fill_gain``, ``force_shear_gain`` when
        set, else from the device's stored force calibration (``<device>/tactile/force.json``
        written by ``thintact calibrate-force``, :func:`thintact_sdk.tactile.calibration.store.find_force_calibration`),
        else the shipped gains.

        Raises
        ------
        CalibrationError
            A stored force calibration that is unreadable or was fitted for another gel.
        """
        from thintact_sdk.tactile.calibration.store import find_force_calibration

        extra = (profile.tactile.model_extra or {}) if profile.tactile is not None else {}
        gains = {"force_normal_gain": NORMAL_GAIN, "force_normal_fill_gain": NORMAL_FILL_GAIN,
                 "force_shear_gain": SHEAR_GAIN}
        stored = find_force_calibration(profile)
        if stored is not None:
            gains.update(read_gains(stored, profile))
        gains.update({k: float(extra[k]) for k in gains if k in extra})
        return cls(
            Elastomer.from_profile(profile),
            gains["force_normal_gain"],
            gains["force_normal_fill_gain"],
            gains["force_shear_gain"],
        )

    def normal_features(self, core: LoadedCore) -> tuple[float, float]:
        """``(E*·V/a, φ·E*·V/a)`` in N: F_z = c_0 · first + c_1 · second.

        φ is clamped to [0.5, 1] (paraboloid cap to flat punch): the gains were fitted on
        0.54–0.75, and a pointed contact (a cone: φ = 1/3) is outside what they describe.
        """
        base = self.elastomer.contact_modulus_mpa * core.volume_mm3 / core.radius_mm
        return base, base * min(max(core.fill, FILL_RANGE[0]), FILL_RANGE[1])

    def estimate(
        self,
        depth_mm: np.ndarray,
        mm_per_px: float,
        threshold_mm: float,
        reference_mm: np.ndarray,
        displacements_mm: np.ndarray,
    ) -> np.ndarray:
        """``(3,)`` float64 force [F_x, F_y, F_z] in newtons.

        Parameters
        ----------
        depth_mm
            ``N × M`` indentation (mm).
        mm_per_px
            Pixel size of ``depth_mm`` (mm).
        threshold_mm
            Contact threshold (mm).
        reference_mm, displacements_mm
            ``K × 2`` marker reference centres and displacements (mm, NaN where lost).

        Returns zeros without contact; F_x, F_y are NaN when no tracked marker lies in the
        loaded core (a marker-free gel: shear unknown).
        """
        core = loaded_core(depth_mm, mm_per_px, threshold_mm)
        if core is None or core.radius_mm <= 0:
            return np.zeros(3)
        base, filled = self.normal_features(core)
        fz = max(0.0, self.normal_gain * base + self.normal_fill_gain * filled)
        disp = np.asarray(displacements_mm, np.float64).reshape(-1, 2)
        inside = markers_in(core.mask, reference_mm, mm_per_px) & np.isfinite(disp).all(axis=1)
        if not inside.any():
            return np.array([np.nan, np.nan, fz])
        shift = disp[inside].mean(axis=0)
        fxy = self.shear_gain * self.elastomer.shear_modulus_mpa * core.radius_mm * shift
        return np.array([fxy[0], fxy[1], fz])


def fit_gains(features: ArrayLike, truth: ArrayLike) -> np.ndarray:
    """Least-squares gains c of ``truth ≈ features @ c`` (``P × G`` features, ``P`` truths)."""
    f = np.asarray(features, np.float64)
    t = np.asarray(truth, np.float64).ravel()
    f = f.reshape(len(t), -1)
    ok = np.isfinite(f).all(axis=1) & np.isfinite(t)
    if ok.sum() < f.shape[1]:
        raise CalibrationError(
            f"{int(ok.sum())} presses with contact for {f.shape[1]} force gains; press more")
    return np.linalg.lstsq(f[ok], t[ok], rcond=None)[0]


def fit_gain(features: ArrayLike, truth: ArrayLike) -> float:
    """Least-squares gain c of ``truth ≈ c · features`` (through the origin)."""
    f = np.asarray(features, np.float64).ravel()
    t = np.asarray(truth, np.float64).ravel()
    ok = np.isfinite(f) & np.isfinite(t)
    denom = float(np.sum(f[ok] ** 2))
    if denom <= 0:
        raise CalibrationError("no press with contact to fit a force gain on")
    return float(np.sum(f[ok] * t[ok]) / denom)


FORMAT = "thintact-force-calibration/1"
"""The ``format`` of a stored force calibration (``<device>/tactile/force.json``)."""
GAIN_KEYS = ("force_normal_gain", "force_normal_fill_gain", "force_shear_gain")


def read_gains(path: Path, profile: Profile) -> dict[str, float]:
    """The gains stored in ``path`` (a ``force.json``), checked against ``profile``'s gel.

    Raises
    ------
    CalibrationError
        Naming the file and field: not JSON, another format, a gain missing or not a finite
        number, or fitted for another E or ν than the profile's (the gains include E*).
    """
    try:
        data = safe_json.loads(path.read_text(), f"force calibration {path}", CalibrationError)
    except (OSError, UnicodeDecodeError) as err:
        raise CalibrationError(f"force calibration {path}: not readable JSON ({err})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CalibrationError(f"force calibration {path}: format is not {FORMAT!r}")
    out: dict[str, float] = {}
    for key in (*GAIN_KEYS, "elastomer_youngs_mpa", "elastomer_poisson"):
        value = data.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise CalibrationError(f"force calibration {path}: {key} must be a finite number, "
                                   f"got {value!r}")
        out[key] = float(value)
    el = Elastomer.from_profile(profile)
    for key, mine in (("elastomer_youngs_mpa", el.youngs_mpa), ("elastomer_poisson", el.poisson)):
        if abs(out[key] - mine) > 1e-3 * max(abs(mine), 1e-9):
            raise CalibrationError(
                f"force calibration {path} was fitted with {key} {out[key]:g} but profile "
                f"{profile.name!r} has {mine:g}; run `thintact calibrate-force --profile "
                f"{profile.name}` again")
    return {k: out[k] for k in GAIN_KEYS}
