"""ThinTact decoders plugin: ``thintact-noniterative``, ``t2s-iterative``, ``flatcam``, ``t2s-closed-form``,
and ``identity`` for lens-based sensors (:mod:`thintact_decoders.identity`).

Every factory is ``factory(profile, settings) -> Decoder``. The calibration bundle comes from
``settings["bundle"]`` / ``settings["calibration"]`` / ``profile.decoder.calibration`` or, for
virtual profiles, the newest bundle under ``calibrations/<profile.name>/``.

Common settings: ``tau`` (overrides the bundle's), ``backend`` (``"numpy"`` default or
``"torch"``), ``dtype`` (``"float32"``), ``device`` (torch), ``gemm_dtype`` (torch:
``"bfloat16"`` for speed). ``thintact-noniterative`` also takes ``fold`` and ``max_rank``;
``t2s-iterative`` takes ``iterations`` (800). ``t2s-closed-form`` (this SDK's extension: the
exact full-T2S Tikhonov minimiser without iterations, see :mod:`thintact_decoders.t2s_closed_form`)
takes ``open_rtol`` and ``max_open_rank`` and uses the bundle's ``tau_t2s_closed_form`` if present.
"""

from __future__ import annotations

from typing import Any

import thintact_sdk
from thintact_decoders.backend import ArrayBackend
from thintact_decoders.flatcam import FlatCamDecoder
from thintact_decoders.identity import IdentityDecoder, make_identity
from thintact_decoders.iterative import T2SIterativeDecoder
from thintact_decoders.loading import resolve_bundle
from thintact_decoders.noniterative import NonIterativeDecoder
from thintact_decoders.t2s_closed_form import T2SClosedFormDecoder
from thintact_sdk.errors import CalibrationError
from thintact_sdk.profile import Profile

__all__ = [
    "ArrayBackend",
    "FlatCamDecoder",
    "IdentityDecoder",
    "NonIterativeDecoder",
    "T2SClosedFormDecoder",
    "T2SIterativeDecoder",
]


def _backend(settings: dict[str, Any]) -> ArrayBackend:
    try:
        return ArrayBackend(
            str(settings.get("backend", "numpy")),
            dtype=str(settings.get("dtype", "float32")),
            device=settings.get("device"),
            gemm_dtype=settings.get("gemm_dtype"),
        )
    except ValueError as err:
        raise CalibrationError(f"decoder settings: {err}") from None


def _tau(bundle_tau: float, settings: dict[str, Any], profile: Profile) -> float:
    if "tau" in settings:
        return float(settings["tau"])
    if bundle_tau > 0:
        return bundle_tau
    if profile.decoder is not None and "tau" in profile.decoder.settings:
        return float(profile.decoder.settings["tau"])
    raise CalibrationError("no Tikhonov tau: the bundle has none; pass settings={'tau': ...}")


def make_noniterative(profile: Profile, settings: dict[str, Any]) -> NonIterativeDecoder:
    """Build the joint-filter decoder for ``profile``."""
    bundle = resolve_bundle(profile, settings)
    if bundle.filter is None:
        raise CalibrationError(f"calibration {bundle.path} has no filter.npz: the non-iterative decoder needs one")
    return NonIterativeDecoder(
        bundle.system_matrices, bundle.filter, _tau(bundle.tau, settings, profile), _backend(settings),
        fold=str(settings.get("fold", "auto")), max_rank=int(settings.get("max_rank", 8)),
    )


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
    return FlatCamDecoder(bundle.system_matrices, _tau(bundle.tau, settings, profile), _backend(settings))


def make_t2s_closed_form(profile: Profile, settings: dict[str, Any]) -> T2SClosedFormDecoder:
    """Build the exact non-iterative full-T2S decoder for ``profile``."""
    bundle = resolve_bundle(profile, settings)
    tau = _tau(float(bundle.meta.get("tau_t2s_closed_form", bundle.tau)), settings, profile)
    return T2SClosedFormDecoder(
        bundle.system_matrices, tau, _backend(settings),
        open_rtol=float(settings.get("open_rtol", 1e-6)),
        max_open_rank=int(settings.get("max_open_rank", 8)),
    )


@thintact_sdk.hookimpl
def thintact_decoders() -> list[thintact_sdk.Component]:
    return [
        thintact_sdk.Component("thintact-noniterative", make_noniterative,
                               "ThinTact joint DCT filter + closed-form Tikhonov (real time)"),
        thintact_sdk.Component("t2s-iterative", make_iterative,
                               "full T2S Tikhonov by Nesterov gradient, 800 iterations (baseline)"),
        thintact_sdk.Component("flatcam", make_flatcam,
                               "FlatCam closed form, coding term only after mean removal (baseline)"),
        thintact_sdk.Component("t2s-closed-form", make_t2s_closed_form,
                               "exact full-T2S Tikhonov without iterations (low-rank open term, Woodbury)"),
        thintact_sdk.Component("identity", make_identity,
                               "lens-based sensors (DIGIT, GelSight Mini): the camera image, scaled and resampled"),
    ]
