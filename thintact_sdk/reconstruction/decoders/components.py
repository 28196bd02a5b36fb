"""The core's decoders as registry components: ``thintact-noniterative``, ``t2s-iterative``,
``flatcam``, ``t2s-closed-form``, and ``identity`` for lens-based sensors
(:mod:`thintact_sdk.reconstruction.decoders.identity`).

This module is a built-in plugin: :func:`thintact_sdk.device.registry.get_registry` registers
it (pluggy style, plugin name ``thintact-sdk``) before the entry points, so its components are
listed by ``thintact plugins`` and reached by name exactly like a third-party decoder's.

Every factory is ``factory(profile, settings) -> Decoder``. The calibration bundle comes from
``settings["bundle"]`` / ``settings["calibration"]`` / ``profile.decoder.calibration`` or, for
virtual profiles, the newest bundle under ``calibrations/<profile.name>/``.

Common settings: ``tau`` (overrides the bundle's), ``dtype`` (``"float32"``). The array backend
of the closed-form decoders is chosen by measurement on this host
(:mod:`thintact_sdk.reconstruction.decoders.backend_selection`); ``backend`` (``"numpy"``/``"torch"``), ``device`` and
``gemm_dtype`` in the settings, or ``THINTACT_BACKEND=torch-float32`` etc. in the environment,
are preferences honoured only where not more than 20 % slower than the best.
``t2s-closed-form`` may solve on the sensor binned 2 × 2 where that is measured faster and as
accurate (:mod:`thintact_sdk.reconstruction.decoders.sensor_binning`; setting ``sensor_bin``: ``"auto"``, 1 never, 2).
``mode_rtol`` (closed-form decoders) drops Tikhonov modes whose filter factor is below it
(default :data:`~thintact_sdk.reconstruction.decoders.modes.DEFAULT_MODE_RTOL`). ``thintact-noniterative`` also takes ``fold`` and ``max_rank``;
``t2s-iterative`` takes ``iterations`` (800). ``t2s-closed-form`` (this SDK's extension: the
exact full-T2S Tikhonov minimiser without iterations, see :mod:`thintact_sdk.reconstruction.decoders.t2s_closed_form`)
takes ``open_rtol`` and ``max_open_rank`` and uses the bundle's ``tau_t2s_closed_form`` if present.
A bundle's per-channel τ (``channel_tau`` → decoder name → one τ per channel, chosen by the
calibration where it helps) is used by that decoder unless ``tau`` is given in the settings.
A bundle's ``scene_prior`` → ``t2s-closed-form`` (generalised Tikhonov with DCT-domain weights,
chosen by the calibration's cross-validation) is used with the bundle's τ; ``tau`` in the
settings means plain Tikhonov at that τ unless ``prior`` (a ``ScenePrior`` or its JSON form) is
given too (``prior: None``: plain Tikhonov whatever the bundle says).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from typing import Any

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.hookspecs import Component, hookimpl
from thintact_sdk.host.compute_threads import prepare_worker_thread
from thintact_sdk.host.machine import host_capabilities, host_fingerprint, kernel_threads_now
from thintact_sdk.interfaces import Decoder
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.decoders.backend import ArrayBackend
from thintact_sdk.reconstruction.decoders.backend_candidates import (
    BackendSpec,
    candidate_specs,
    parse_preference,
    preference_from_settings,
)
from thintact_sdk.reconstruction.decoders.backend_selection import (
    MEASURED_AT,
    BackendPreferenceWarning,
    make_probes,
    select_backend,
)
from thintact_sdk.reconstruction.decoders.flatcam import FlatCamDecoder
from thintact_sdk.reconstruction.decoders.identity import make_identity
from thintact_sdk.reconstruction.decoders.iterative import T2SIterativeDecoder
from thintact_sdk.reconstruction.decoders.loading import resolve_bundle
from thintact_sdk.reconstruction.decoders.modes import DEFAULT_MODE_RTOL, TauSpec
from thintact_sdk.reconstruction.decoders.noniterative import NonIterativeDecoder
from thintact_sdk.reconstruction.decoders.sensor_binning import binnable_build, binning_offered
from thintact_sdk.reconstruction.decoders.t2s_closed_form import T2SClosedFormDecoder
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices

REMEASURE_ENV = "THINTACT_BACKEND_REMEASURE"  # set (not "0"): measure again, replace the cached record
EMULATED_BF16 = ("bfloat16 is emulated in software on this CPU (no AVX512-BF16, AMX or BF16 flag), "
                 "about 100x slower than float32")

__all__ = [
    "EMULATED_BF16",
    "REMEASURE_ENV",
    "make_flatcam",
    "make_iterative",
    "make_noniterative",
    "make_t2s_closed_form",
    "thintact_decoders",
]


def _backend(settings: dict[str, Any]) -> ArrayBackend:
    """The backend the settings name (the iterative baseline: not measured), emulated
    bfloat16 replaced by the working precision with a warning."""
    gemm = settings.get("gemm_dtype")
    if gemm == "bfloat16" and not host_capabilities().native_bf16:
        warnings.warn(f"gemm_dtype bfloat16 not used: {EMULATED_BF16}", BackendPreferenceWarning, stacklevel=3)
        gemm = None
    try:
        return ArrayBackend(
            str(settings.get("backend", "numpy")),
            dtype=str(settings.get("dtype", "float32")),
            device=settings.get("device"),
            gemm_dtype=gemm,
        )
    except ValueError as err:
        raise CalibrationError(f"decoder settings: {err}") from None


def _selected(name: str, profile: Profile, settings: dict[str, Any], sm: SystemMatrices,
              build: Callable[..., Decoder], binnable: bool = False) -> Decoder:
    """``build`` on the backend measured fastest (and accurate) for this host and operator
    (``binnable``: ``build(backend, b)`` also solves on the sensor binned b × b, which is
    then a candidate where the sensor oversamples the scene)."""
    dtype = str(settings.get("dtype", "float32"))
    caps = host_capabilities()  # loads torch where it is installed
    prepare_worker_thread()  # a kernel-thread hold in force applies to torch too from here on
    env = os.environ.get("THINTACT_BACKEND", "").strip()
    preferred: BackendSpec | None
    try:
        if env:
            preferred, source = parse_preference(env, dtype), "THINTACT_BACKEND"
        else:
            preferred, source = preference_from_settings(settings, dtype), "decoder.settings"
    except ValueError as err:
        where = "THINTACT_BACKEND" if env else "decoder settings"
        raise CalibrationError(f"{where}: {err}") from None
    not_candidates = {} if caps.native_bf16 else {"torch-bfloat16": EMULATED_BF16}
    (r, s), (n, m) = sm.sensor_shape, sm.scene_shape
    # the threads the candidates are timed on: a Sensor on a 2-core host decodes (and so
    # selects) on one kernel thread, `thintact bench reconstruct` on the library's
    key = (f"{host_fingerprint(caps)}|{name}|{sm.channels}x{r}x{s}->{n}x{m}|{dtype}|{kernel_threads_now()}"
           f"|{MEASURED_AT}")
    try:
        sensor_bin = binning_offered((r, s), (n, m), sm.channels, settings.get("sensor_bin", "auto")) if binnable else 1
    except ValueError as err:
        raise CalibrationError(str(err)) from None
    decoder, _ = select_backend(
        build, lambda: make_probes(sm, profile.noise), candidate_specs(caps, dtype, sensor_bin=sensor_bin),
        key, preferred, source, not_candidates, remeasure=os.environ.get(REMEASURE_ENV, "") not in ("", "0"))
    return decoder


def _mode_rtol(settings: dict[str, Any]) -> float:
    return float(settings.get("mode_rtol", DEFAULT_MODE_RTOL))


def _tau(bundle_tau: float, settings: dict[str, Any], profile: Profile) -> float:
    if "tau" in settings:
        return float(settings["tau"])
    if bundle_tau > 0:
        return bundle_tau
    if profile.decoder is not None and "tau" in profile.decoder.settings:
        return float(profile.decoder.settings["tau"])
    raise CalibrationError("no Tikhonov tau: the bundle has none; pass settings={'tau': ...}")


def _decoder_tau(name: str, bundle_tau: float, bundle: CalibrationBundle, settings: dict[str, Any],
                 profile: Profile) -> TauSpec:
    """The settings' ``tau``, else the bundle's per-channel τ for decoder ``name``, else
    :func:`_tau`."""
    per_channel = (bundle.meta.get("channel_tau") or {}).get(name)
    if "tau" not in settings and per_channel is not None:
        return [float(t) for t in per_channel]
    return _tau(bundle_tau, settings, profile)


def make_noniterative(profile: Profile, settings: dict[str, Any]) -> NonIterativeDecoder:
    """Build the joint-filter decoder for ``profile``."""
    bundle = resolve_bundle(profile, settings)
    if bundle.filter is None:
        raise CalibrationError(f"calibration {bundle.path} has no filter.npz: the non-iterative decoder needs one")
    tau, jf = _decoder_tau("thintact-noniterative", bundle.tau, bundle, settings, profile), bundle.filter
    return _selected("thintact-noniterative", profile, settings, bundle.system_matrices,
                     lambda xp: NonIterativeDecoder(
                         bundle.system_matrices, jf, tau, xp, fold=str(settings.get("fold", "auto")),
                         max_rank=int(settings.get("max_rank", 8)), mode_rtol=_mode_rtol(settings)))  # type: ignore[return-value]


def make_iterative(profile: Profile, settings: dict[str, Any]) -> T2SIterativeDecoder:
    """Build the iterative T2S (Nesterov) decoder for ``profile``."""
    bundle = resolve_bundle(profile, settings)
    return T2SIterativeDecoder(
        bundle.system_matrices, _tau(bundle.tau, settings, profile),
        iterations=int(settings.get("iterations", 800)), backend=_backend(settings),
        gradient=str(settings.get("gradient", "gram")),
    )


def make_flatcam(profile: Profile, settings: dict[str, Any]) -> FlatCamDecoder:
    """Build the FlatCam closed-form decoder for ``profile``."""
    bundle = resolve_bundle(profile, settings)
    tau = _tau(bundle.tau, settings, profile)
    return _selected("flatcam", profile, settings, bundle.system_matrices,
                     lambda xp: FlatCamDecoder(bundle.system_matrices, tau, xp, _mode_rtol(settings)))  # type: ignore[return-value]


def _prior(name: str, bundle: CalibrationBundle, settings: dict[str, Any]) -> ScenePrior | None:
    """The settings' ``prior`` (``None`` there: plain Tikhonov); else, unless ``tau`` is given,
    the bundle's ``scene_prior`` for decoder ``name``; else none (plain Tikhonov)."""
    if "prior" in settings:
        given = settings["prior"]
        if given is None or isinstance(given, ScenePrior):
            return given
        return ScenePrior.from_json(given, "decoder settings: prior")
    if "tau" in settings:
        return None
    stored = (bundle.meta.get("scene_prior") or {}).get(name)
    return None if stored is None else ScenePrior.from_json(stored, f"{bundle.path}: scene_prior → {name!r}")


def make_t2s_closed_form(profile: Profile, settings: dict[str, Any]) -> T2SClosedFormDecoder:
    """Build the exact non-iterative full-T2S decoder for ``profile`` (on the sensor binned
    2 × 2 where the selection finds that faster and as accurate)."""
    bundle = resolve_bundle(profile, settings)
    tau = _decoder_tau("t2s-closed-form", float(bundle.meta.get("tau_t2s_closed_form", bundle.tau)), bundle,
                       settings, profile)
    prior = _prior("t2s-closed-form", bundle, settings)
    build = binnable_build(bundle.system_matrices, tau, lambda sm, t, xp: T2SClosedFormDecoder(
        sm, t, xp, open_rtol=float(settings.get("open_rtol", 1e-6)),
        max_open_rank=int(settings.get("max_open_rank", 8)), mode_rtol=_mode_rtol(settings), prior=prior))
    return _selected("t2s-closed-form", profile, settings, bundle.system_matrices, build,
                     binnable=True)  # type: ignore[return-value]


@hookimpl
def thintact_decoders() -> list[Component]:
    return [
        Component("thintact-noniterative", make_noniterative,
                  "ThinTact joint DCT filter + closed-form Tikhonov (real time)",
                  traits=("calibration-candidate", "tau-key=tau", "joint-filter")),
        Component("t2s-iterative", make_iterative,
                               "full T2S Tikhonov by Nesterov gradient, 800 iterations (baseline)"),
        Component("flatcam", make_flatcam,
                               "FlatCam closed form, coding term only after mean removal (baseline)"),
        Component("t2s-closed-form", make_t2s_closed_form,
                  "exact full-T2S Tikhonov without iterations (low-rank open term, Woodbury)",
                  traits=("calibration-candidate", "tau-key=tau_t2s_closed_form", "scene-prior")),
        Component("identity", make_identity,
                               "lens-based sensors (DIGIT, GelSight Mini): the camera image, scaled and resampled"),
    ]
