"""Device profiles (``thintact-profile/1``, CONTRACTS §2) as pydantic models.

A profile holds the contract fields (sensor, scene, mask, geometry, noise, physics) and
the optional sections a real device needs: which camera plugin and its settings, which
light controller and port, which decoder and calibration, which display drives
calibration, and the tactile-pipeline parameters.

Profiles are loaded from YAML or JSON files, or by name from the shipped profiles
(``thintact_sdk/profiles``) and any directory listed in ``THINTACT_PROFILE_PATH``.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from thintact_sdk.errors import ProfileError

PROFILE_FORMAT = "thintact-profile/1"
SHIPPED_PROFILE_DIR = Path(__file__).parent / "profiles"


class _Section(BaseModel):
    """Base of every profile section: extra keys are kept (contracts allow optional fields)."""

    model_config = ConfigDict(extra="allow", frozen=False)


class SensorSpec(_Section):
    """The measurement image after Bayer binning: ``rows`` R × ``cols`` S × channels."""

    rows: int = Field(gt=0, description="R, measurement rows after binning")
    cols: int = Field(gt=0, description="S, measurement columns after binning")
    pixel_pitch_um: float = Field(gt=0, description="binned pixel pitch p in um")
    channels: list[str] = Field(default_factory=lambda: ["R", "G", "B"], min_length=1)


class SceneSpec(_Section):
    """The scene grid (LCD pixels / membrane): ``rows`` N × ``cols`` M, pitch in um."""

    rows: int = Field(gt=0, description="N, scene rows")
    cols: int = Field(gt=0, description="M, scene columns")
    pixel_pitch_um: float = Field(gt=0, description="scene pixel pitch in um")


class MaskSpec(_Section):
    """Separable binary mask: cell (i, j) is open when phi_rows[i]·phi[j] = +1."""

    feature_um: float = Field(gt=0, description="mask cell side delta in um")
    phi: list[int] = Field(min_length=1, description="K entries of +1/-1 along x (columns)")
    phi_rows: list[int] | None = Field(
        default=None, description="K entries of +1/-1 along y (rows); defaults to phi"
    )
    design: str | None = Field(default=None, description="mask plugin that made phi (mls, ga, ...)")

    @field_validator("phi", "phi_rows")
    @classmethod
    def _plus_minus_one(cls, v: list[int] | None) -> list[int] | None:
        if v is None:
            return v
        bad = sorted({x for x in v if x not in (1, -1)})
        if bad:
            raise ValueError(f"entries must be +1 or -1, found {bad[:5]}")
        return v

    @model_validator(mode="after")
    def _same_length(self) -> MaskSpec:
        if self.phi_rows is not None and len(self.phi_rows) != len(self.phi):
            raise ValueError(
                f"phi_rows has {len(self.phi_rows)} entries but phi has {len(self.phi)}; "
                "the mask is K×K"
            )
        return self

    @property
    def K(self) -> int:  # noqa: N802 - the paper's symbol
        return len(self.phi)

    @property
    def rows_vector(self) -> list[int]:
        return self.phi_rows if self.phi_rows is not None else self.phi


class GeometrySpec(_Section):
    """Distances along the optical axis: scene → mask z, mask → sensor d (mm)."""

    scene_to_mask_mm: float = Field(gt=0, description="z, scene plane to mask in mm")
    mask_to_sensor_mm: float = Field(gt=0, description="d, mask to sensor in mm")

    @property
    def total_mm(self) -> float:
        """H = z + d in mm."""
        return self.scene_to_mask_mm + self.mask_to_sensor_mm


class NoiseSpec(_Section):
    """Sensor noise model (CONTRACTS §4), all in digital numbers (DN)."""

    black_level_dn: float = Field(ge=0)
    read_noise_dn: float = Field(ge=0)
    electrons_per_dn: float = Field(gt=0)
    saturation_dn: float = Field(gt=0)

    @model_validator(mode="after")
    def _black_below_saturation(self) -> NoiseSpec:
        if self.black_level_dn >= self.saturation_dn:
            raise ValueError("black_level_dn must be below saturation_dn")
        return self


class CameraConfig(_Section):
    """Which camera plugin produces raw frames, and its settings."""

    plugin: str = Field(description="camera plugin name, e.g. 'virtual', 'genicam', 'uvc', 'replay'")
    settings: dict[str, Any] = Field(default_factory=dict)
    bayer_pattern: Literal["RGGB", "BGGR", "GRBG", "GBRG", "none"] = Field(
        default="RGGB", description="CFA layout of the raw frame; 'none' for already binned RGB"
    )


class LightConfig(_Section):
    """Which LED controller plugin drives the sensor's LEDs, where, and the default levels."""

    plugin: str
    port: str | None = Field(default=None, description="serial port path or pyserial URL")
    settings: dict[str, Any] = Field(default_factory=dict)
    intensities: list[float] | None = Field(
        default=None, description="LED levels in [0, 1] set when the sensor opens"
    )


class DecoderConfig(_Section):
    """Which decoder reconstructs scenes and from which calibration."""

    plugin: str = Field(default="thintact-noniterative")
    calibration: str | None = Field(
        default=None, description="calibration bundle directory (relative to the profile file)"
    )
    settings: dict[str, Any] = Field(default_factory=dict)


class DisplayConfig(_Section):
    """The LCD that shows calibration patterns: plugin, which display, sensing area placement."""

    plugin: str = Field(default="virtual")
    display_index: int = Field(default=0, ge=0)
    pixel_pitch_um: float = Field(default=31.5, gt=0)
    origin_px: tuple[int, int] = Field(
        default=(0, 0), description="(x, y) of the sensing area's top-left pixel on the panel"
    )
    settle_s: float = Field(default=0.1, ge=0, description="wait after a pattern change")
    settings: dict[str, Any] = Field(default_factory=dict)


class TactileConfig(_Section):
    """Tactile pipeline parameters (photometric stereo, contact, markers)."""

    mm_per_px: float | None = Field(default=None, gt=0, description="scene pixel size in mm")
    contact_threshold_mm: float = Field(default=0.1, gt=0)
    lut: str | None = Field(default=None, description="photometric-stereo LUT file")
    real2sim: str | None = Field(
        default=None,
        description="Real2Sim generator file (thintact real2sim train): real images are "
        "translated to simulation-like ones before photometric stereo",
    )
    marker_pitch_mm: float = Field(default=1.5, gt=0)
    marker_diameter_mm: float = Field(default=0.5, gt=0)


class CalibrationLimits(_Section):
    """Pass/fail limits for a calibration's validation.

    A unit fails a validation scene that it reconstructs more than ``psnr_margin_db`` worse
    than its own design is predicted to (``thintact_sdk.calibration.prediction``);
    ``min_psnr_db`` and ``min_ssim`` are optional fixed floors on the means.
    """

    psnr_margin_db: float = Field(default=1.5, ge=0, description="allowed shortfall (dB) "
                                  "below the PSNR predicted for the design, per scene")
    min_psnr_db: float | None = None
    min_ssim: float | None = None


class Profile(BaseModel):
    """A complete ThinTact device profile (``thintact-profile/1``)."""

    model_config = ConfigDict(extra="allow")

    format: str
    name: str = Field(min_length=1)
    description: str | None = None
    sensor: SensorSpec
    scene: SceneSpec
    mask: MaskSpec
    geometry: GeometrySpec
    noise: NoiseSpec
    physics: dict[str, dict[str, Any]] = Field(default_factory=dict)
    camera: CameraConfig | None = None
    light: LightConfig | None = None
    decoder: DecoderConfig | None = None
    display: DisplayConfig | None = None
    tactile: TactileConfig | None = None
    calibration_limits: CalibrationLimits | None = None

    # where the profile was read from (not serialised): resolves relative paths
    _source: Path | None = None

    @field_validator("format")
    @classmethod
    def _known_format(cls, v: str) -> str:
        if v != PROFILE_FORMAT:
            raise ValueError(f"unknown profile format {v!r}; this SDK reads {PROFILE_FORMAT!r}")
        return v

    @property
    def source(self) -> Path | None:
        """The file this profile was loaded from, if any."""
        return self._source

    def resolve_path(self, p: str | os.PathLike[str]) -> Path:
        """Resolve a path named in the profile relative to the profile's own directory."""
        path = Path(p).expanduser()
        if path.is_absolute() or self._source is None:
            return path
        return (self._source.parent / path).resolve()

    def contract_dict(self) -> dict[str, Any]:
        """The profile as a plain dict (JSON-serialisable), without unset optional sections."""
        return self.model_dump(mode="json", exclude_none=True)

    def content_hash(self) -> str:
        """SHA-256 of the physics-relevant contract fields (what a calibration depends on)."""
        d = self.model_dump(
            mode="json",
            include={"sensor", "scene", "mask", "geometry", "noise", "physics"},
            exclude_none=True,
        )
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()

    def with_physics(self, physics: dict[str, dict[str, Any]]) -> Profile:
        """A copy of this profile with the ``physics`` section replaced."""
        p = self.model_copy(update={"physics": physics}, deep=True)
        p._source = self._source
        return p


def _format_validation_error(err: ValidationError, where: str) -> str:
    lines = [f"invalid profile {where}:"]
    for e in err.errors():
        loc = ".".join(str(x) for x in e["loc"]) or "(top level)"
        msg = e["msg"]
        if e["type"] == "missing":
            msg = "field required (missing)"
        lines.append(f"  - {loc}: {msg}")
    return "\n".join(lines)


def profile_from_dict(data: Any, where: str = "(in memory)") -> Profile:
    """Validate a dict as a profile.

    Raises
    ------
    ProfileError
        With one line per problem, each naming the field (dotted path) and the reason.
    """
    if not isinstance(data, dict):
        raise ProfileError(f"invalid profile {where}: expected a mapping, got {type(data).__name__}")
    if "format" not in data:
        raise ProfileError(f"invalid profile {where}:\n  - format: field required (missing)")
    try:
        return Profile.model_validate(data)
    except ValidationError as err:
        raise ProfileError(_format_validation_error(err, where)) from None


def read_profile_file(path: str | os.PathLike[str]) -> Profile:
    """Load and validate a profile from a ``.json``, ``.yaml`` or ``.yml`` file."""
    p = Path(path)
    if not p.is_file():
        raise ProfileError(f"profile file not found: {p}")
    text = p.read_text(encoding="utf-8")
    try:
        if p.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            data = yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as err:
        raise ProfileError(f"cannot parse profile {p}: {err}") from None
    prof = profile_from_dict(data, where=str(p))
    prof._source = p.resolve()
    return prof


def profile_search_path() -> list[Path]:
    """Directories searched for profiles by name: ``THINTACT_PROFILE_PATH`` first, then shipped."""
    dirs = [Path(d) for d in os.environ.get("THINTACT_PROFILE_PATH", "").split(os.pathsep) if d]
    return dirs + [SHIPPED_PROFILE_DIR]


def available_profiles() -> dict[str, Path]:
    """Map profile name → file for every profile found on the search path (first wins)."""
    found: dict[str, Path] = {}
    for d in profile_search_path():
        if not d.is_dir():
            continue
        for f in sorted(d.iterdir()):
            if f.suffix.lower() not in (".json", ".yaml", ".yml"):
                continue
            try:
                name = read_profile_file(f).name
            except ProfileError:
                continue
            found.setdefault(name, f)
    return found


def load_profile(name_or_path: str | os.PathLike[str] | Profile) -> Profile:
    """Load a profile given a :class:`Profile`, a file path or a profile name.

    Parameters
    ----------
    name_or_path
        An existing profile object, a path to a JSON/YAML file, or the ``name`` of a
        profile on :func:`profile_search_path`.
    """
    if isinstance(name_or_path, Profile):
        return name_or_path
    p = Path(name_or_path)
    if p.suffix.lower() in (".json", ".yaml", ".yml") or p.exists():
        return read_profile_file(p)
    profiles = available_profiles()
    if str(name_or_path) in profiles:
        return read_profile_file(profiles[str(name_or_path)])
    known = ", ".join(sorted(profiles)) or "(none)"
    raise ProfileError(f"no profile named {str(name_or_path)!r}; known profiles: {known}")


def write_profile(profile: Profile, path: str | os.PathLike[str]) -> Path:
    """Write a profile as JSON (``.json``) or YAML (otherwise); returns the path."""
    p = Path(path)
    d = profile.contract_dict()
    p.parent.mkdir(parents=True, exist_ok=True)
    if p.suffix.lower() == ".json":
        p.write_text(json.dumps(d, indent=1) + "\n", encoding="utf-8")
    else:
        p.write_text(yaml.safe_dump(d, sort_keys=False), encoding="utf-8")
    return p
