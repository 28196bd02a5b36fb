"""What this host offers for decoding and what a decoder chooses here: the library behind
``thintact doctor``.

:func:`host_report` gathers the CPU's capabilities, the float32 GEMM rate measured now and,
for a profile's decoder, the backend it selects on this host (from the per-host cache, or
measured again with ``remeasure``); :attr:`HostReport.data` is what ``--json`` prints.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from typing import Any

from thintact_sdk.errors import ProfileError
from thintact_sdk.formats.profiles import Profile

__all__ = ["HostReport", "decoder_choice", "host_report"]


def decoder_choice(profile: Profile, remeasure: bool = False) -> tuple[Any, str]:
    """``(decoder, how it was built)``: the profile's decoder, or, for a profile without a
    calibration bundle, the closed form on its directly generated matrices (same shapes, the
    fallback of ``thintact bench tactile``). With ``remeasure`` the decoder's backends are
    measured again and this host's cached choice replaced (the environment is restored after).

    Raises
    ------
    ProfileError
        ``profile`` has no decoder section.
    """
    from thintact_sdk.apps.benchmarks.tactile_accuracy import _latency_decoder
    from thintact_sdk.reconstruction.decoders.components import REMEASURE_ENV

    if profile.decoder is None:
        raise ProfileError(f"profile {profile.name!r} has no decoder section")
    old = os.environ.get(REMEASURE_ENV)
    if remeasure:  # measure now and replace this host's cached record
        os.environ[REMEASURE_ENV] = "1"
    try:
        decoder, _, how = _latency_decoder(profile)
        return decoder, how
    finally:
        if old is None:
            os.environ.pop(REMEASURE_ENV, None)
        else:
            os.environ[REMEASURE_ENV] = old


@dataclass(frozen=True)
class HostReport:
    """What :func:`host_report` found.

    Attributes
    ----------
    data
        The plain report (``thintact doctor --json``): ``host`` (capabilities),
        ``sgemm_gflops`` (float32 GEMM 1024³, GFLOP/s, measured now), ``profile``,
        ``decoder``, ``decoder_source``, ``backend`` (``chosen``, ``measured_ms``,
        ``psnr_cost_db``, ``not_candidates``, ``from_cache``, ``note``; None when the decoder
        fixes its backend) and ``warnings`` (raised while the decoder was built).
    capabilities
        The :class:`~thintact_sdk.host.machine.HostCapabilities` (its ``lines()`` for text).
    backend_choice
        The decoder's backend choice object (its ``summary()`` for text), or None.
    sgemm_gflops
        The measured GEMM rate, GFLOP/s, unrounded.
    """

    data: dict[str, Any]
    capabilities: Any
    backend_choice: Any
    sgemm_gflops: float


def host_report(profile: Profile, remeasure: bool = False) -> HostReport:
    """The host's capabilities, the GEMM rate measured now and ``profile``'s decoder backend
    choice (:func:`decoder_choice`), as ``thintact doctor`` reports them.

    Raises
    ------
    ProfileError
        ``profile`` has no decoder section.
    """
    from thintact_sdk.host.machine import host_capabilities
    from thintact_sdk.host.roofline import measure_sgemm_gflops

    caps = host_capabilities()
    sgemm = measure_sgemm_gflops(1, 1024, 1024, 1024)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        decoder, how = decoder_choice(profile, remeasure)
    choice = getattr(decoder, "backend_choice", None)
    data: dict[str, Any] = {
        "host": caps.as_dict(), "sgemm_gflops": round(sgemm, 1), "profile": profile.name,
        "decoder": getattr(decoder, "name", type(decoder).__name__), "decoder_source": how,
        "backend": None if choice is None else {
            "chosen": choice.chosen, "measured_ms": choice.measured_ms, "psnr_cost_db": choice.psnr_cost_db,
            "not_candidates": choice.unavailable, "from_cache": choice.from_cache, "note": choice.note},
        "warnings": [str(w.message) for w in caught],
    }
    return HostReport(data, caps, choice, sgemm)
