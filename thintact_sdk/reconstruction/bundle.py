"""Calibration bundles: ``calibrations/<device>/<YYYYmmddTHHMMSS>/``.

A bundle directory holds

``calibration.json``
    ``{"format": "thintact-calibration/1", "profile", "profile_hash", "software_version",
    "created", "tau", "exposure_us", "metrics": {...}, "source": "wizard|recording|simulator|import"}``
    (``import``: matrices calibrated elsewhere, :mod:`thintact_sdk.formats.matrices`);
    optional ``tau_t2s_closed_form`` (that decoder's τ) and ``channel_tau``
    (``{decoder name: [τ per channel]}``, DN², where the calibration found a τ per channel better)
    and ``scene_prior`` (``{decoder name: {"kind": "dct-power", "alpha", "k0"}}``: that decoder
    solves generalised Tikhonov with this :class:`~thintact_sdk.reconstruction.scene_prior.ScenePrior`
    at its τ; absent: plain Tikhonov)
``system_matrices.npz``
    :class:`~thintact_sdk.reconstruction.t2s.SystemMatrices` (DN above black per display unit).
``filter.npz``
    :class:`~thintact_sdk.reconstruction.joint_filter.JointFilter` (Φf, Φs: ``C × R × S`` each).
``report.html``
    optional, written by whoever made the bundle.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats import safe_json
from thintact_sdk.reconstruction.joint_filter import JointFilter
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices

if TYPE_CHECKING:
    from thintact_sdk.formats.profiles import Profile

CALIBRATION_FORMAT = "thintact-calibration/1"
META_FILE = "calibration.json"
MATRICES_FILE = "system_matrices.npz"
FILTER_FILE = "filter.npz"
REPORT_FILE = "report.html"
SOURCES = ("wizard", "recording", "simulator", "import")
TIMESTAMP_FORMAT = "%Y%m%dT%H%M%S"


def timestamp_name(when: datetime | None = None) -> str:
    """Directory name of a new bundle: UTC ``YYYYmmddTHHMMSS``."""
    return (when or datetime.now(UTC)).strftime(TIMESTAMP_FORMAT)


@dataclass
class CalibrationBundle:
    """System matrices, trained joint filter and metadata of one calibration.

    Attributes
    ----------
    system_matrices
        The T2S matrices.
    filter
        The trained joint filter (``None`` only for a bundle used by filter-free decoders).
    meta
        The contents of ``calibration.json``.
    path
        The directory it was loaded from / saved to, if any.
    """

    system_matrices: SystemMatrices
    filter: JointFilter | None
    meta: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    @classmethod
    def create(
        cls,
        profile: Profile,
        system_matrices: SystemMatrices,
        joint_filter: JointFilter | None,
        *,
        tau: float,
        source: str,
        exposure_us: float | None = None,
        metrics: dict[str, Any] | None = None,
        **extra: Any,
    ) -> CalibrationBundle:
        """A new bundle for ``profile`` with the ``calibration.json`` fields filled in.

        Parameters
        ----------
        tau
            Tikhonov weight τ the decoder should use (DN² units of the system matrices).
        source
            ``"wizard"``, ``"recording"``, ``"simulator"`` or ``"import"``.
        exposure_us
            Camera exposure (us) the matrices were measured at.
        metrics
            Validation figures (e.g. ``{"psnr_db": {...}, "ssim": {...}}``).
        """
        import thintact_sdk

        if source not in SOURCES:
            raise CalibrationError(f"source must be one of {', '.join(SOURCES)}, got {source!r}")
        meta: dict[str, Any] = {
            "format": CALIBRATION_FORMAT,
            "profile": profile.name,
            "profile_hash": profile.content_hash(),
            "software_version": thintact_sdk.__version__,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "tau": float(tau),
            "exposure_us": None if exposure_us is None else float(exposure_us),
            "metrics": dict(metrics or {}),
            "source": source,
            **extra,
        }
        return cls(system_matrices, joint_filter, meta)

    # -- convenience -------------------------------------------------------------------
    @property
    def tau(self) -> float:
        """Tikhonov weight τ stored in the bundle (DN²; 0.0 when the bundle has none)."""
        value = self.meta.get("tau")
        return float(value) if value is not None else 0.0

    def matches_profile(self, profile: Profile) -> bool:
        """Whether the bundle was made for this profile's physics (``profile_hash`` equal)."""
        return self.meta.get("profile_hash") == profile.content_hash()

    def check_shapes(self, profile: Profile) -> None:
        """Raise CalibrationError unless the matrices fit the profile's sensor and scene grids."""
        sm = self.system_matrices
        want_sensor = (profile.sensor.rows, profile.sensor.cols)
        want_scene = (profile.scene.rows, profile.scene.cols)
        if sm.sensor_shape != want_sensor or sm.scene_shape != want_scene:
            raise CalibrationError(
                f"calibration {self.path or ''} is for sensor {sm.sensor_shape} / scene "
                f"{sm.scene_shape}, but profile {profile.name!r} has sensor {want_sensor} / "
                f"scene {want_scene}"
            )

    # -- persistence -------------------------------------------------------------------
    def save(self, directory: str | os.PathLike[str]) -> Path:
        """Write the bundle into ``directory`` (created); returns it."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        meta = {"format": CALIBRATION_FORMAT, **self.meta}
        self.system_matrices.save(d / MATRICES_FILE)
        if self.filter is not None:
            self.filter.save(d / FILTER_FILE)
        (d / META_FILE).write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
        self.path = d
        return d

    @classmethod
    def load(cls, directory: str | os.PathLike[str]) -> CalibrationBundle:
        """Read a bundle directory; raises CalibrationError naming what is missing or wrong."""
        d = Path(directory)
        if not d.is_dir():
            raise CalibrationError(f"calibration bundle not found: {d}")
        meta_path = d / META_FILE
        if not meta_path.is_file():
            raise CalibrationError(f"{d} is not a calibration bundle: no {META_FILE}")
        try:
            meta = safe_json.loads(meta_path.read_text(encoding="utf-8"),
                                   f"{meta_path} is not a calibration bundle: cannot read it;",
                                   CalibrationError)
        except (OSError, UnicodeDecodeError) as err:
            raise CalibrationError(f"{meta_path} is not a calibration bundle: cannot read it ({err})") from None
        if not isinstance(meta, dict) or meta.get("format") != CALIBRATION_FORMAT:
            got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
            raise CalibrationError(f"{meta_path}: format {got!r}, expected {CALIBRATION_FORMAT!r}")
        _check_meta(meta, meta_path)
        sm = SystemMatrices.load(d / MATRICES_FILE)
        check_conditioning(sm, d / MATRICES_FILE)
        jf = JointFilter.load(d / FILTER_FILE) if (d / FILTER_FILE).is_file() else None
        if jf is not None and (jf.sensor_shape != sm.sensor_shape or jf.channels != sm.channels):
            raise CalibrationError(
                f"{d}: filter is {jf.channels}×{jf.sensor_shape} but system matrices are "
                f"{sm.channels}×{sm.sensor_shape}"
            )
        return cls(sm, jf, meta, d)


CODING_RCOND = 1e-9
"""Smallest accepted ratio of a coding matrix's smallest to largest singular value: below it
the matrix is (numerically) rank-deficient and scenes it maps alike cannot be told apart.
Matrices stored in single precision are judged at their own rounding level instead when that
is higher (``4·sqrt(max(rows, cols))·eps`` of the stored type)."""


def check_conditioning(sm: SystemMatrices, where: str | os.PathLike[str]) -> None:
    """Refuse system matrices no decoder can invert, naming ``where``, the matrix and channel.

    The coding matrices ``Pc`` (``R × N``) and ``Qc`` (``S × M``) of every channel must be
    non-zero and of full rank ``min(rows, cols)``: their smallest singular value at least
    :data:`CODING_RCOND` (or the stored type's rounding level) times their largest. The open matrices ``Po``, ``Qo`` may be zero
    (FlatCam's one-term model) or smooth and low-rank (the open term of T2S) and are not judged.

    Raises
    ------
    CalibrationError
        For an all-zero or rank-deficient coding matrix.
    """
    import numpy as np

    for name in ("Pc", "Qc"):
        stack = getattr(sm, name)
        for c in range(stack.shape[0]):
            stored = np.asarray(stack[c])
            a = stored.astype(np.float64)
            rtol = max(CODING_RCOND, 4.0 * math.sqrt(max(a.shape)) * float(np.finfo(stored.dtype).eps))
            what = f"{where}: system matrix {name} (channel {c}, {a.shape[0]}×{a.shape[1]})"
            if a.size == 0 or not np.any(a):
                raise CalibrationError(f"{what} is all zero: the calibration records no signal "
                                       "(a failed or empty calibration); recalibrate")
            sv = np.linalg.svd(a, compute_uv=False)
            ratio = float(sv[-1] / sv[0])
            if not ratio >= rtol:
                rank = int(np.count_nonzero(sv > sv[0] * rtol))
                raise CalibrationError(
                    f"{what} is rank-deficient: rank {rank} of {len(sv)}, smallest relative "
                    f"singular value {ratio:.2g} (< {rtol:.2g}); scenes it maps alike "
                    "cannot be told apart; recalibrate")


POSITIVE_META_FIELDS = ("tau", "tau_t2s_closed_form", "exposure_us")
"""``calibration.json`` fields that, when present and not null, must be finite numbers > 0
(τ in DN², exposure in us)."""


def _check_meta(meta: dict[str, Any], meta_path: Path) -> None:
    """Refuse ``calibration.json`` fields of the wrong type or sign, naming file and field."""
    for key in POSITIVE_META_FIELDS:
        value = meta.get(key)
        if value is None:
            continue
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if not (number and math.isfinite(value) and value > 0):
            raise CalibrationError(
                f"{meta_path}: field {key!r} is {value!r}, which is invalid: it must be a finite "
                "number > 0 (or null when unknown)"
            )
    for key in ("profile", "profile_hash"):
        if key in meta and not isinstance(meta[key], str):
            raise CalibrationError(f"{meta_path}: field {key!r} must be a string, got {meta[key]!r}")
    channel_tau = meta.get("channel_tau")
    if channel_tau is not None:
        ok = isinstance(channel_tau, dict) and all(
            isinstance(v, list) and v and all(
                isinstance(t, int | float) and not isinstance(t, bool) and math.isfinite(t) and t > 0 for t in v)
            for v in channel_tau.values())
        if not ok:
            raise CalibrationError(
                f"{meta_path}: field 'channel_tau' is {channel_tau!r}, which is invalid: it must map "
                "decoder names to lists of finite numbers > 0 (one per channel)")
    priors = meta.get("scene_prior")
    if priors is not None:
        if not isinstance(priors, dict):
            raise CalibrationError(f"{meta_path}: field 'scene_prior' is {priors!r}, which is invalid: it must "
                                   "map decoder names to scene priors")
        for name, prior in priors.items():
            ScenePrior.from_json(prior, f"{meta_path}: field 'scene_prior' → {name!r}")
    if "metrics" in meta and not isinstance(meta["metrics"], dict):
        raise CalibrationError(f"{meta_path}: field 'metrics' must be an object")


def find_latest(device_dir: str | os.PathLike[str]) -> Path:
    """The newest bundle (by its ``YYYYmmddTHHMMSS`` name) under ``device_dir``.

    Raises
    ------
    CalibrationError
        When ``device_dir`` holds no bundle.
    """
    d = Path(device_dir)
    candidates = sorted(
        p for p in (d.iterdir() if d.is_dir() else []) if p.is_dir() and (p / META_FILE).is_file()
    )
    if not candidates:
        raise CalibrationError(
            f"no calibration bundle under {d}; run the calibration wizard or "
            "tools/make_virtual_calibration.py"
        )
    return candidates[-1]
