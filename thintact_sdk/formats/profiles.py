"""Device profiles (``thintact-profile/1``, CONTRACTS §2) as pydantic models.

A profile holds the contract fields (sensor, scene, mask, geometry, noise, physics) and
the optional sections a real device needs: which camera plugin and its settings, which
light controller and port, which decoder and calibration, which display drives
calibration, and the tactile-pipeline parameters.

Profiles are loaded from YAML or JSON files, or by name from the shipped profiles
(``thintact_sdk/data/profiles``) and any directory listed in ``THINTACT_PROFILE_PATH``.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import warnings
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator
from pydantic_core import PydanticCustomError

from thintact_sdk.errors import ProfileError, ThinTactError
from thintact_sdk.formats import safe_yaml as yaml_safe
from thintact_sdk.pixels.tone_curve import ToneCurveSpec, check_table_file

PROFILE_FORMAT = "thintact-profile/1"
SHIPPED_PROFILE_DIR = Path(__file__).resolve().parents[1] / "data" / "profiles"

MAX_PIXELS_PER_SIDE = 16384
"""Largest sensor / scene side in pixels (a 16k × 16k frame is already 256 Mpx)."""
MAX_MASK_CELLS = 16384
"""Largest K (mask cells per side)."""
MAX_PITCH_UM = 10_000.0
"""Largest pixel pitch or mask feature in um (10 mm)."""
MIN_PITCH_UM = 0.1
"""Smallest pixel pitch, mask feature or tactile pixel in um (100 nm: below the wavelength
of visible light, finer than any image sensor or display; smaller values are typos)."""
MAX_DISTANCE_MM = 1000.0
"""Largest scene → mask or mask → sensor distance in mm."""
MIN_DISTANCE_MM = 1e-3
"""Smallest scene → mask or mask → sensor distance in mm (1 um)."""
MAX_PROFILE_BYTES = 16 * 2**20
"""Largest profile file read (16 MiB; two 16384-entry mask vectors take about 200 kB)."""
MEMORY_FRACTION = 1 / 8
"""Share of this host's physical memory one array implied by a profile may take: the
pipeline holds several such arrays at once (raw, binned, reconstruction, depth, kernels)."""
KNOWN_CHANNELS = ("R", "G", "B", "mono", "Gr", "Gb")
"""Channel names a profile may list: the Bayer-binned colours, one monochrome channel, or the
four Bayer sites ``R, Gr, Gb, B`` kept apart (FlatCam's layout)."""
BAYER_PLANES = ["R", "Gr", "Gb", "B"]
"""The per-Bayer-site channel layout, in this order (:func:`thintact_sdk.pixels.bayer.split_bayer`)."""
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
_PLUGIN_NAME_RE = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*:)?[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")

Count = Annotated[int, Field(strict=True, gt=0, le=MAX_PIXELS_PER_SIDE)]
"""A pixel count: a true integer (not a bool or a float) in [1, 16384]."""
PitchUm = Annotated[float, Field(ge=MIN_PITCH_UM, le=MAX_PITCH_UM, allow_inf_nan=False)]
"""A finite pixel pitch in um, 0.1 um to 10 mm."""
MaskCellUm = Annotated[float, Field(ge=MIN_PITCH_UM, le=100 * MAX_PITCH_UM, allow_inf_nan=False)]
"""A mask cell side in um, 0.1 um to 1 m: a lens-based sensor's profile declares an open
aperture, one cell as wide as the field (``digit``: 15 mm)."""
DistanceMm = Annotated[float, Field(gt=0, le=MAX_DISTANCE_MM, allow_inf_nan=False)]
"""A finite positive distance in mm, at most 1 m."""
AxialMm = Annotated[float, Field(ge=MIN_DISTANCE_MM, le=MAX_DISTANCE_MM, allow_inf_nan=False)]
"""A distance along the optical axis in mm, 1 um to 1 m."""
TactilePxMm = Annotated[float, Field(ge=MIN_PITCH_UM / 1000, le=MAX_PITCH_UM / 1000, allow_inf_nan=False)]
"""A tactile pixel size in mm, 0.1 um to 10 mm (as a pixel pitch)."""
FiniteNonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
FinitePos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
PluginName = Annotated[str, Field(pattern=_PLUGIN_NAME_RE.pattern)]
"""A plugin component name, optionally namespaced by its plugin: ``virtual`` or ``acme:virtual``."""


class _Section(BaseModel):
    """Base of every profile section: extra keys are kept (contracts allow optional fields)."""

    model_config = ConfigDict(extra="allow", frozen=False)


class SensorSpec(_Section):
    """The measurement image after Bayer binning: ``rows`` R × ``cols`` S × channels."""

    rows: Count = Field(description="R, measurement rows after binning")
    cols: Count = Field(description="S, measurement columns after binning")
    pixel_pitch_um: PitchUm = Field(description="binned pixel pitch p in um")
    channels: list[str] = Field(default_factory=lambda: ["R", "G", "B"], min_length=1, max_length=4)
    tone_curve: ToneCurveSpec | None = Field(
        default=None, description="the camera's tone curve, undone before binning and decoding "
        "(thintact_sdk.pixels.tone_curve); absent: the camera delivers linear DN",
    )

    @field_validator("channels")
    @classmethod
    def _known_channels(cls, v: list[str]) -> list[str]:
        unknown = [c for c in v if c not in KNOWN_CHANNELS]
        if unknown:
            raise ValueError(f"unknown channel(s) {unknown}; known: {', '.join(KNOWN_CHANNELS)}")
        if len(set(v)) != len(v):
            raise ValueError(f"channels repeat: {v}")
        if "mono" in v and len(v) > 1:
            raise ValueError("'mono' is the only channel of a monochrome sensor")
        if ("Gr" in v or "Gb" in v or len(v) == 4) and v != BAYER_PLANES:
            raise ValueError(f"per-Bayer-site planes are exactly {BAYER_PLANES} (in this order), got {v}")
        return v


class SceneSpec(_Section):
    """The scene grid (LCD pixels / membrane): ``rows`` N × ``cols`` M, pitch in um."""

    rows: Count = Field(description="N, scene rows")
    cols: Count = Field(description="M, scene columns")
    pixel_pitch_um: PitchUm = Field(description="scene pixel pitch in um")


class MaskSpec(_Section):
    """Separable binary mask: cell (i, j) is open when phi_rows[i]·phi[j] = +1."""

    feature_um: MaskCellUm = Field(description="mask cell side delta in um")
    phi: list[Annotated[int, Field(strict=True)]] = Field(
        min_length=1, max_length=MAX_MASK_CELLS, description="K entries of +1/-1 along x (columns)"
    )
    phi_rows: list[Annotated[int, Field(strict=True)]] | None = Field(
        default=None, max_length=MAX_MASK_CELLS,
        description="K entries of +1/-1 along y (rows); defaults to phi",
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

    scene_to_mask_mm: AxialMm = Field(description="z, scene plane to mask in mm")
    mask_to_sensor_mm: AxialMm = Field(description="d, mask to sensor in mm")

    @property
    def total_mm(self) -> float:
        """H = z + d in mm."""
        return self.scene_to_mask_mm + self.mask_to_sensor_mm


class NoiseSpec(_Section):
    """Sensor noise model (CONTRACTS §4), all in digital numbers (DN)."""

    black_level_dn: FiniteNonNeg
    read_noise_dn: FiniteNonNeg
    electrons_per_dn: FinitePos
    saturation_dn: FinitePos

    @model_validator(mode="after")
    def _black_below_saturation(self) -> NoiseSpec:
        if self.black_level_dn >= self.saturation_dn:
            raise ValueError("black_level_dn must be below saturation_dn")
        return self


class CameraConfig(_Section):
    """Which camera plugin produces raw frames, and its settings."""

    plugin: PluginName = Field(
        description="camera plugin name, e.g. 'virtual', 'genicam', 'uvc', 'replay' (or 'acme:virtual')"
    )
    settings: dict[str, Any] = Field(default_factory=dict)
    bayer_pattern: Literal["RGGB", "BGGR", "GRBG", "GBRG", "none"] = Field(
        default="RGGB", description="CFA layout of the raw frame; 'none' for already binned RGB"
    )


class LightConfig(_Section):
    """Which LED controller plugin drives the sensor's LEDs, where, and the default levels."""

    plugin: PluginName
    port: str | None = Field(default=None, description="serial port path or pyserial URL")
    settings: dict[str, Any] = Field(default_factory=dict)
    intensities: list[Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]] | None = Field(
        default=None, max_length=256, description="LED levels in [0, 1] set when the sensor opens"
    )


class DecoderConfig(_Section):
    """Which decoder reconstructs scenes and from which calibration."""

    plugin: PluginName = Field(description="the decoder's registry name (thintact plugins lists them); "
                               "required: the profile, not the code, chooses the decoder")
    calibration: str | None = Field(
        default=None, description="calibration bundle directory (relative to the profile file)"
    )
    settings: dict[str, Any] = Field(default_factory=dict)


class DisplayConfig(_Section):
    """The LCD that shows calibration patterns: plugin, which display, sensing area placement."""

    plugin: PluginName = Field(description="the display's registry name (thintact plugins lists them)")
    display_index: int = Field(default=0, ge=0, strict=True)
    pixel_pitch_um: PitchUm = Field(default=31.5)
    origin_px: tuple[Annotated[int, Field(strict=True, ge=0)], Annotated[int, Field(strict=True, ge=0)]] = Field(
        default=(0, 0), description="(x, y) of the sensing area's top-left pixel on the panel"
    )
    settle_s: float = Field(default=0.1, ge=0, le=60, allow_inf_nan=False,
                            description="wait after a pattern change in s")
    settings: dict[str, Any] = Field(default_factory=dict)


class TactileConfig(_Section):
    """Tactile pipeline parameters (photometric stereo, contact, markers)."""

    mm_per_px: TactilePxMm | None = Field(default=None, description="scene pixel size in mm")
    contact_threshold_mm: DistanceMm = Field(default=0.1)
    lut: str | None = Field(default=None, description="photometric-stereo LUT file")
    real2sim: str | None = Field(
        default=None,
        description="Real2Sim generator file (thintact real2sim train): real images are "
        "translated to simulation-like ones before photometric stereo",
    )
    marker_pitch_mm: DistanceMm = Field(default=1.5)
    marker_diameter_mm: DistanceMm = Field(default=0.5)


class CalibrationLimits(_Section):
    """Pass/fail limits for a calibration's validation.

    A unit fails a validation scene that it reconstructs more than ``psnr_margin_db`` worse
    than its own design is predicted to (``thintact_sdk.calibration.prediction``);
    ``min_psnr_db`` and ``min_ssim`` are optional fixed floors on the means.
    """

    psnr_margin_db: float = Field(default=1.5, ge=0, allow_inf_nan=False,
                                  description="allowed shortfall (dB) below the PSNR predicted "
                                  "for the design, per scene")
    min_psnr_db: float | None = Field(default=None, allow_inf_nan=False)
    min_ssim: float | None = Field(default=None, ge=-1, le=1, allow_inf_nan=False)


PER_RGB_EFFECTS = ("diffraction", "stray_light", "color_crosstalk")
"""CONTRACTS §5 effects with one parameter value per R, G, B channel."""


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

    @field_validator("name")
    @classmethod
    def _name_not_path(cls, v: str) -> str:
        if not _NAME_RE.match(v):
            raise ValueError(
                f"{v!r} is not a profile name: use 1-64 letters, digits, '.', '_' or '-', "
                "starting with a letter or digit (no path separators)"
            )
        return v

    @field_validator("physics")
    @classmethod
    def _known_physics(cls, v: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        from thintact_sdk.simulation.effects import resolve_physics

        try:
            resolve_physics(v)
        except ThinTactError as err:
            raise ValueError(str(err)) from None
        return v

    @model_validator(mode="after")
    def _physics_channels(self) -> Profile:
        """Effects whose parameters are per R, G, B need a sensor of those three channels (a
        four-plane Bayer sensor's stray light broadcast 3 values onto 4 planes: ValueError)."""
        per_rgb = [e for e in PER_RGB_EFFECTS if e in self.physics]
        if per_rgb and len(self.sensor.channels) != 3:
            raise PydanticCustomError(
                "physics_channels",
                "physics.{effect}: its parameters are per R, G, B; this sensor has {n} channels ({ch})",
                {"effect": per_rgb[0], "n": len(self.sensor.channels), "ch": ", ".join(self.sensor.channels)})
        return self

    @model_validator(mode="after")
    def _within_limits(self) -> Profile:
        problem = resource_problem(self)
        if problem:
            raise PydanticCustomError("profile_limit", "{problem}", {"problem": problem})
        return self

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


_TACTILE_NUMBERS: dict[str, tuple[float, float]] = {
    "elastomer_sigma_mm": (0.0, MAX_DISTANCE_MM),
    "elastomer_youngs_mpa": (1e-6, 1e6),
    "elastomer_poisson": (0.0, 0.5),
    "force_normal_gain": (-math.inf, math.inf),
    "force_normal_fill_gain": (-math.inf, math.inf),
    "force_shear_gain": (-math.inf, math.inf),
}
"""Optional ``tactile`` keys the tactile pipeline reads as numbers, with their closed ranges."""
ELASTOMER_SIGMA_MM = 0.25
"""The tactile simulator's elastomer blur when ``tactile.elastomer_sigma_mm`` is absent
(:attr:`thintact_sdk.tactile.interpretation.grid.TactileParams.elastomer_sigma_mm`), in mm."""


def host_memory_bytes() -> int:
    """Physical memory of this host in bytes (``SC_PHYS_PAGES × SC_PAGE_SIZE``; 16 GiB when
    the host does not say)."""
    try:
        pages, size = os.sysconf("SC_PHYS_PAGES"), os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 16 * 2**30
    return int(pages) * int(size) if pages > 0 and size > 0 else 16 * 2**30


def array_limit_bytes() -> int:
    """The most bytes one array implied by a profile may take: :data:`MEMORY_FRACTION` of
    :func:`host_memory_bytes`."""
    return int(host_memory_bytes() * MEMORY_FRACTION)


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.1f} MiB"


def implied_arrays(profile: Profile) -> list[tuple[str, str, int]]:
    """The largest arrays the SDK allocates for ``profile``: ``(fields, what, bytes)``.

    - the raw Bayer mosaic, ``2R × 2S`` float64 (the binned ``R × S × C`` frame is no larger);
    - the scene grid: the tactile simulator's ``2N × 2M`` float64 convolution grids (a
      reconstruction ``N × M × C`` float64 is no larger);
    - the system matrices ``Φ_L`` (``R × N``) and ``Φ_R`` (``S × M``) float64 per channel.
    """
    s, sc = profile.sensor, profile.scene
    c = len(s.channels)
    return [
        ("sensor.rows × sensor.cols", f"a {2 * s.rows}×{2 * s.cols} float64 raw frame",
         8 * 4 * s.rows * s.cols),
        ("scene.rows × scene.cols", f"a {2 * sc.rows}×{2 * sc.cols} float64 tactile grid",
         8 * 4 * sc.rows * sc.cols),
        ("sensor × scene", f"{c} channel(s) of {s.rows}×{sc.rows} and {s.cols}×{sc.cols} float64 "
         "system matrices", 8 * c * (s.rows * sc.rows + s.cols * sc.cols)),
    ]


def _tactile_problem(profile: Profile) -> str | None:
    """A physically impossible or unbounded tactile value (with a ``tactile`` section)."""
    t = profile.tactile
    if t is None:
        return None
    extra = t.model_extra or {}
    for key, (low, high) in _TACTILE_NUMBERS.items():
        if key not in extra:
            continue
        v = extra[key]
        try:
            x = float(v) if not isinstance(v, bool) else math.nan
        except (TypeError, ValueError, OverflowError):
            x = math.nan
        if not (math.isfinite(x) and low <= x <= high):
            rng = "a finite number" if math.isinf(low) else f"a finite number in [{low:g}, {high:g}]"
            return f"tactile.{key}: expected {rng}, got {v!r}"
    mm = float(t.mm_per_px) if t.mm_per_px is not None else profile.scene.pixel_pitch_um / 1000
    via = "tactile.mm_per_px" if t.mm_per_px is not None else "scene.pixel_pitch_um"
    side = max(profile.scene.rows, profile.scene.cols)
    sigma = float(extra.get("elastomer_sigma_mm", ELASTOMER_SIGMA_MM))
    if sigma / mm > side:
        given = "" if "elastomer_sigma_mm" in extra else " (the default)"
        return (f"tactile.elastomer_sigma_mm: {sigma:g} mm{given} is {sigma / mm:.3g} px at {mm:g} "
                f"mm/px ({via}), wider than the {side} px scene grid it blurs")
    if t.marker_diameter_mm / mm > MAX_PIXELS_PER_SIDE:
        return (f"tactile.marker_diameter_mm: {t.marker_diameter_mm:g} mm is "
                f"{t.marker_diameter_mm / mm:.3g} px at {mm:g} mm/px ({via}), over "
                f"{MAX_PIXELS_PER_SIDE} px")
    if t.marker_pitch_mm < mm:
        return (f"tactile.marker_pitch_mm: {t.marker_pitch_mm:g} mm is below one pixel "
                f"({mm:g} mm, {via}): more markers than pixels")
    if t.marker_diameter_mm >= t.marker_pitch_mm:
        return (f"tactile.marker_diameter_mm: {t.marker_diameter_mm:g} mm is not below "
                f"tactile.marker_pitch_mm ({t.marker_pitch_mm:g} mm): the markers would overlap")
    return None


def resource_problem(profile: Profile) -> str | None:
    """Why ``profile`` cannot be run on this host, or None.

    Checked when a profile is validated, before anything is allocated: every array of
    :func:`implied_arrays` must fit :func:`array_limit_bytes`, and with a ``tactile``
    section the tactile numbers must be finite and in range, the elastomer blur (a Gaussian
    of ``elastomer_sigma_mm`` / ``mm_per_px`` pixels) no wider than the scene grid, a marker
    at most :data:`MAX_PIXELS_PER_SIDE` pixels across, the marker pitch at least one pixel
    (no more markers than pixels) and above the marker diameter. The reason starts with the dotted field.
    """
    limit = array_limit_bytes()
    for fields, what, size in implied_arrays(profile):
        if size > limit:
            return (f"{fields}: {what} of {_gib(size)}, over the {_gib(limit)} one array may "
                    f"take on this host ({MEMORY_FRACTION:.3g} of {_gib(host_memory_bytes())} memory)")
    return _tactile_problem(profile)


def validation_error_line(err: ValidationError) -> str:
    """One line for a pydantic error: the first error's dotted field and message, then
    ``(and N more: f1, f2, f3, ...)`` naming up to three more fields when there are more."""
    errors = err.errors()
    if not errors:
        return str(err).splitlines()[0]
    e = errors[0]
    loc = ".".join(str(x) for x in e["loc"])
    msg = "field required (missing)" if e["type"] == "missing" else e["msg"]
    msg = msg.removeprefix("Value error, ").removeprefix("Assertion failed, ")
    msg = " ".join(msg.split())
    text = f"{loc}: {msg}" if loc else msg
    if len(errors) > 1:
        others = list(dict.fromkeys(".".join(str(x) for x in o["loc"]) or "(top level)" for o in errors[1:]))
        named = ", ".join(others[:3]) + (", ..." if len(others) > 3 else "")
        text += f" (and {len(errors) - 1} more: {named})"
    return text


def _format_validation_error(err: ValidationError, where: str) -> str:
    return f"invalid profile {where}: {validation_error_line(err)}"


def profile_from_dict(data: Any, where: str = "(in memory)") -> Profile:
    """Validate a dict as a profile.

    Raises
    ------
    ProfileError
        One line: the first problem's field (dotted path) and reason, and how many more.
    """
    if not isinstance(data, dict):
        raise ProfileError(f"invalid profile {where}: expected a mapping, got {type(data).__name__}")
    if "format" not in data:
        raise ProfileError(f"invalid profile {where}: format: field required (missing)")
    try:
        return Profile.model_validate(data)
    except ValidationError as err:
        raise ProfileError(_format_validation_error(err, where)) from None


def read_profile_file(path: str | os.PathLike[str]) -> Profile:
    """Load and validate a profile from a ``.json``, ``.yaml`` or ``.yml`` file.

    Raises
    ------
    ProfileError
        The file is missing, unreadable, larger than :data:`MAX_PROFILE_BYTES`, not UTF-8,
        not JSON/YAML (read by :mod:`thintact_sdk.formats.safe_yaml`: bounded aliases, no duplicate
        keys, core-schema tags only; JSON without duplicate keys), or fails validation; one
        line naming the file (and the line, or the dotted field).
    """
    p = Path(path)
    if not p.is_file():
        raise ProfileError(f"profile file not found: {p}")
    data = yaml_safe.read_file(p, "profile", ProfileError, MAX_PROFILE_BYTES,
                               as_json=p.suffix.lower() == ".json")
    prof = profile_from_dict(data, where=str(p))
    prof._source = p.resolve()
    try:
        check_table_file(prof)
    except ProfileError as err:
        raise ProfileError(f"invalid profile {p}: {err}") from None
    return prof


def profile_search_path() -> list[Path]:
    """Directories searched for profiles by name: ``THINTACT_PROFILE_PATH`` first, then shipped."""
    dirs = [Path(d) for d in os.environ.get("THINTACT_PROFILE_PATH", "").split(os.pathsep) if d]
    return dirs + [SHIPPED_PROFILE_DIR]


def _scan_profiles() -> tuple[dict[str, Path], dict[str, tuple[Path, str]]]:
    """Profiles on the search path: ``name → file`` and the broken files, ``stem → (file, why)``."""
    found: dict[str, Path] = {}
    broken: dict[str, tuple[Path, str]] = {}
    for d in profile_search_path():
        if not d.is_dir():
            continue
        for f in sorted(d.iterdir()):
            if f.suffix.lower() not in (".json", ".yaml", ".yml"):
                continue
            try:
                name = read_profile_file(f).name
            except ProfileError as err:
                broken.setdefault(f.stem, (f, str(err)))
                continue
            found.setdefault(name, f)
    return found, broken


def available_profiles() -> dict[str, Path]:
    """Map profile name → file for every valid profile on the search path (first wins).

    A file that cannot be read or validated is skipped with a :class:`UserWarning` naming
    it, so one broken file never hides the others.
    """
    found, broken = _scan_profiles()
    _warn_skipped(broken)
    return found


def _warn_skipped(broken: dict[str, tuple[Path, str]]) -> None:
    for f, why in broken.values():
        first = why.splitlines()[0].rstrip(":")
        warnings.warn(f"skipping profile file {f}: {first.split(f'{f}: ', 1)[-1]}", UserWarning, stacklevel=3)


def load_profile(name_or_path: str | os.PathLike[str] | Profile) -> Profile:
    """Load a profile given a :class:`Profile`, a file path or a profile name.

    Parameters
    ----------
    name_or_path
        An existing profile object, a path to a JSON/YAML file, or the ``name`` of a
        profile on :func:`profile_search_path`.

    Raises
    ------
    ProfileError
        No such profile, or the file of that name on the search path is broken (the
        message names the file and the problem).
    """
    if isinstance(name_or_path, Profile):
        return name_or_path
    p = Path(name_or_path)
    if p.suffix.lower() in (".json", ".yaml", ".yml") or p.exists():
        return read_profile_file(p)
    profiles, broken = _scan_profiles()
    name = str(name_or_path)
    if name in profiles:
        _warn_skipped(broken)
        return read_profile_file(profiles[name])
    if name in broken:
        raise ProfileError(broken[name][1])
    known = ", ".join(sorted(profiles)) or "(none)"
    skipped = f" (skipped broken files: {', '.join(str(f) for f, _ in broken.values())})" if broken else ""
    raise ProfileError(f"no profile named {name!r}; known profiles: {known}{skipped}")


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
