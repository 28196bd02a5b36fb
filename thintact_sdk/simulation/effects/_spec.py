"""Typed description of an effect of CONTRACTS §5: everything about it in one declaration.

An effect module defines one :class:`EffectSpec` named ``SPEC`` that says

- where it acts (``stage``) and its parameters with units, defaults and physical bounds;
- how it is applied: ``forward`` for the scene, signal and DN stages (the simulator calls
  it in stage order), or ``kernel`` for kernel-stage effects (the fields of the imaging
  kernel's parameters it sets; the kernel code itself stays in ``imaging/``);
- its words (``describe``, and ``distinguish``: what recording tells it from another effect);
- how the diagnosis fits it (``fit``, a :class:`FitSpec`).

:func:`thintact_sdk.simulation.effects.register_effect` adds a new one to the registry, and the
simulator and the diagnosis pick it up from there.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np

from thintact_sdk.errors import ThinTactError


class _PixelGrid(Protocol):
    @property
    def rows(self) -> int: ...
    @property
    def cols(self) -> int: ...
    @property
    def pixel_pitch_um(self) -> float: ...


class _Gaps(Protocol):
    @property
    def scene_to_mask_mm(self) -> float: ...
    @property
    def mask_to_sensor_mm(self) -> float: ...
    @property
    def total_mm(self) -> float: ...


class _NoiseLevels(Protocol):
    @property
    def black_level_dn(self) -> float: ...
    @property
    def saturation_dn(self) -> float: ...


class _MaskCells(Protocol):
    @property
    def feature_um(self) -> float: ...


class DeviceProfile(Protocol):
    """What effects read of a device profile (:class:`thintact_sdk.formats.profiles.Profile` is one).

    A structural type, so that ``physics`` does not import ``profile`` (which validates its
    ``physics`` section with :func:`thintact_sdk.simulation.effects.resolve_physics`).
    """

    @property
    def sensor(self) -> _PixelGrid: ...
    @property
    def scene(self) -> _PixelGrid: ...
    @property
    def geometry(self) -> _Gaps: ...
    @property
    def noise(self) -> _NoiseLevels: ...
    @property
    def mask(self) -> _MaskCells: ...


STAGES = ("scene", "kernel", "signal", "dn")
"""Where an effect acts: on the scene before imaging, inside the imaging kernel, on the
linear signal (unit-free, linear), or on the signal in DN (needs the per-channel gain)."""

Stage = Literal["scene", "kernel", "signal", "dn"]
Params = Mapping[str, Any]
#: ``(array, resolved parameters, profile) -> array``: scene ``F×N×M×C`` display values,
#: signal ``F×R×S×C`` simulator units, or DN above black ``F×R×S×C``
StageForward = Callable[[np.ndarray, Params, DeviceProfile], np.ndarray]
#: one separable term ``(P: R × N, Q: S × M)`` of ``Y_c = Σ P X_c Qᵀ``
Term = tuple[np.ndarray, np.ndarray]
#: ``(resolved parameters, profile) -> (term -> the terms it becomes)``
TermMap = Callable[[Params, DeviceProfile], Callable[[np.ndarray, np.ndarray], list[Term]]]
#: ``(resolved parameters, profile) -> {KernelParams field: value}``
KernelContribution = Callable[[Params, DeviceProfile], dict[str, Any]]
ProfileVector = Callable[[DeviceProfile], np.ndarray]
#: how the diagnosis computes an effect (see :class:`FitSpec`)
Domain = Literal["optical", "post", "dn", "linear"]


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: unit, default, physical bounds (applied to every element of a list)."""

    unit: str
    default: Any
    bounds: tuple[float, float]
    description: str = ""
    shape: tuple[int, ...] = ()


@dataclass(frozen=True)
class DataSearch:
    """Start values read off the measurement (no first-order signature needed).

    Attributes
    ----------
    starts
        ``(measured DN at the fitted pixels, profile) -> trial vectors`` (null excluded).
    exact
        ``(best trial vector, measured) -> True`` when the data give the value exactly.
    refine_width
        ``vector -> half-width`` of the parabola that refines the best trial otherwise.
    """

    starts: Callable[[np.ndarray, DeviceProfile], list[np.ndarray]]
    exact: Callable[[np.ndarray, np.ndarray], bool]
    refine_width: Callable[[np.ndarray], float]


@dataclass(frozen=True)
class Proxy:
    """An effect too expensive to score that another effect's fit can stand in for.

    Attributes
    ----------
    source
        Name of the effect whose fit (in the same round) points at this one.
    start
        ``(source's fitted vector, profile) -> start vector or None`` (None: the source
        fit does not point at this effect).
    widths
        Relative half-widths of the parabolas that refine the start, in turn.
    stand_in
        ``start vector -> bool``: whether a source finding pointing here this far is a
        plausible stand-in for this effect when the diagnosis could not screen it on the
        device (its kernel out of reach, ``binned.not_screened``); the finding then names
        this effect among its alternatives. None: never named so.
    """

    source: str
    start: Callable[[np.ndarray, DeviceProfile], np.ndarray | None]
    widths: tuple[float, ...] = (0.02, 0.004)
    stand_in: Callable[[np.ndarray], bool] | None = None


@dataclass(frozen=True)
class FitSpec:
    """How the diagnosis fits an effect: a flat vector of fit parameters and its hints.

    Attributes
    ----------
    domain
        ``"optical"``: the simulator computes it (re-simulating every frame); ``"post"``:
        a map of the simulated signal that the diagnosis applies with the effect's
        ``forward`` (no re-simulation); ``"dn"``: a map after the gain (``dn_response``);
        ``"linear"``: additive terms solved in closed form next to the gains (``basis``).
    labels
        Names of the flat fit parameters, with units.
    null, step
        Functions of the profile giving ``(k,)`` vectors: the value with the effect absent
        and the typical amplitude of its first-order signature.
    to_params, from_params
        Flat vector ↔ the effect's parameters.
    bounds
        ``profile -> (lower, upper)`` where the fit vector is not the parameters one to one
        or the profile narrows them; default: the :class:`ParamSpec` bounds, flattened.
    channelwise
        Parameter i acts only on channel i: one simulation gives every Jacobian column.
    signed
        Per parameter: may the change from the null have either sign (else one-sided).
    score_step
        ``profile -> (k,)`` finite-difference steps of the score's first-order signature
        where a step of ``step`` would be needlessly expensive to simulate (a kernel whose
        cost grows with the parameter, e.g. the rotated mask's rank with the angle);
        default ``step``.
    slow_params
        Parameters that switch the simulator to a slow path: left at null in the score,
        refined last by parabolas when time allows.
    costly
        Every simulation rebuilds an expensive kernel: the full fit may use all the time left.
    joint_refit
        Its values may move when a later effect is fitted (False: kept where accepted).
    search, proxy
        Scored from values read off the data, or started from another effect's fit.
    dn_response
        ``(L, vector, profile) -> (h(L), h'(L))`` for the DN domain (L linear DN above black).
    clip_level_dn
        ``(vector, profile) -> absolute DN`` at which pixels stop counting (a clip).
    basis
        ``(rows, cols) -> T × R × S`` additive terms (linear domain).
    report
        ``(coefficients C × T, basis T × R × S, profile) -> parameters`` (linear domain).
    """

    domain: Domain
    labels: tuple[str, ...]
    null: ProfileVector
    step: ProfileVector
    to_params: Callable[[np.ndarray, DeviceProfile], dict[str, Any]]
    from_params: Callable[[Params, DeviceProfile], np.ndarray]
    bounds: Callable[[DeviceProfile], tuple[np.ndarray, np.ndarray]] | None = None
    channelwise: bool = False
    signed: tuple[bool, ...] = ()
    score_step: ProfileVector | None = None
    slow_params: tuple[int, ...] = ()
    costly: bool = False
    joint_refit: bool = True
    search: DataSearch | None = None
    proxy: Proxy | None = None
    dn_response: Callable[[np.ndarray, np.ndarray, DeviceProfile], tuple[np.ndarray, np.ndarray]] | None = None
    clip_level_dn: Callable[[np.ndarray, DeviceProfile], float] | None = None
    basis: Callable[[int, int], np.ndarray] | None = None
    report: Callable[[np.ndarray, np.ndarray, DeviceProfile], dict[str, Any]] | None = None

    @property
    def k(self) -> int:
        """Number of fit parameters."""
        return len(self.labels)


@dataclass(frozen=True)
class EffectSpec:
    """An effect: name, stage, parameters, application, words and how to fit it.

    Attributes
    ----------
    order
        Position within its stage (lower first): the simulator applies the effects of a
        stage in this order (e.g. stray light before sensor gamma before the clip).
    forward
        The effect on its stage's array (scene, signal and DN stages).
    kernel
        The imaging-kernel parameters it sets (kernel stage).
    validate
        Extra check of resolved parameters beyond shapes and bounds (raises
        :class:`~thintact_sdk.errors.ThinTactError`).
    separable_terms
        For a scene- or signal-stage effect that keeps the model a sum of separable
        per-channel terms (:meth:`~thintact_sdk.simulation.simulator.Simulator.open_coding_terms`):
        ``(parameters, profile) -> f`` with ``f(P, Q)`` the terms one term becomes. None:
        the effect breaks separability (kernel-stage effects: the kernel decides).
    describe
        ``(parameters, profile) -> one sentence``: what the model left out, with its size.
    distinguish
        ``{other effect: what recording tells the two apart}``.
    fit
        How the diagnosis fits it (None: the diagnosis does not try it).
    reads_beyond_pixel
        For an effect after the kernel: what a pixel's value takes from outside the pixel
        itself, in words (None: nothing, so a window of the sensor can be evaluated alone,
        e.g. :meth:`~thintact_sdk.simulation.simulator.Simulator.linear_window`).
    """

    name: str
    stage: Stage
    description: str
    params: dict[str, ParamSpec] = field(default_factory=dict)
    order: int = 0
    forward: StageForward | None = None
    kernel: KernelContribution | None = None
    validate: Callable[[Params], None] | None = None
    separable_terms: TermMap | None = None
    describe: Callable[[Params, DeviceProfile], str] | None = None
    distinguish: dict[str, str] = field(default_factory=dict)
    fit: FitSpec | None = None
    reads_beyond_pixel: str | None = None

    def __post_init__(self) -> None:
        if self.stage not in STAGES:
            raise ThinTactError(f"effect {self.name!r}: stage {self.stage!r} is not one of {STAGES}")
        if self.stage == "kernel" and self.kernel is None:
            raise ThinTactError(f"effect {self.name!r}: a kernel-stage effect declares `kernel`")
        if self.stage != "kernel" and self.forward is None:
            raise ThinTactError(f"effect {self.name!r}: a {self.stage}-stage effect declares `forward`")

    def defaults(self) -> dict[str, Any]:
        """The parameters at their neutral defaults (the effect then changes nothing)."""
        return {k: p.default for k, p in self.params.items()}

    def param_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` of the parameters flattened in declaration order."""
        lo: list[float] = []
        hi: list[float] = []
        for p in self.params.values():
            n = int(np.prod(p.shape)) if p.shape else 1
            lo += [p.bounds[0]] * n
            hi += [p.bounds[1]] * n
        return np.asarray(lo, np.float64), np.asarray(hi, np.float64)

    def fit_bounds(self, profile: DeviceProfile) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the fit vector: :attr:`FitSpec.bounds` or the parameters' own."""
        if self.fit is None:
            raise ThinTactError(f"effect {self.name!r} declares no fit")
        if self.fit.bounds is not None:
            return self.fit.bounds(profile)
        return self.param_bounds()


def const(*v: float) -> ProfileVector:
    """A profile-independent ``(k,)`` vector (for :class:`FitSpec` ``null``/``step``)."""
    arr = np.asarray(v, np.float64)
    return lambda _p: arr.copy()


def scalar_fit(
    key: str, null: float, step: float, signed: bool, domain: Domain = "optical", **kw: Any
) -> FitSpec:
    """:class:`FitSpec` of an effect with one scalar parameter ``key``."""

    def to(v: np.ndarray, _p: DeviceProfile) -> dict[str, Any]:
        return {key: round(float(v[0]), 6)}

    def frm(d: Params, _p: DeviceProfile) -> np.ndarray:
        return np.array([float(d[key])])

    return FitSpec(domain, (key,), const(null), const(step), to, frm, signed=(signed,), **kw)
