"""``thintact doctor``: what this host offers for decoding and what a decoder chooses here.

Prints the CPU (model, SIMD level, native bfloat16), numpy's BLAS and its threads, torch and
its threads, GPUs, the float32 GEMM rate measured now, and, for a profile's decoder, the
backend the decoder selects on this host with the measured alternatives (from the per-host
cache when it was measured before; ``--remeasure`` measures again and replaces the cached
record, e.g. after the first measurement ran on a busy machine).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from thintact_sdk.errors import ProfileError

REMEASURE_ENV = "THINTACT_BACKEND_REMEASURE"  # read by the decoders plugin (the core imports no plugin)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("doctor", help="host capabilities and the decoder backend chosen on this host")
    p.add_argument("--profile", default="thintact-paper",
                   help="device profile whose decoder is checked (default thintact-paper)")
    p.add_argument("--remeasure", action="store_true",
                   help="measure the backends again (e.g. on a quiet machine) and replace this host's "
                        "cached choice")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def _decoder_choice(profile: Any, remeasure: bool) -> tuple[Any, str]:
    """``(decoder, how it was built)``: the profile's decoder, or, for a profile without a
    calibration bundle, the closed form on its directly generated matrices (same shapes, the
    fallback of ``thintact bench tactile``)."""
    import os

    from thintact_sdk.apps.benchmarks.tactile_accuracy import _latency_decoder

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


def run(args: argparse.Namespace) -> int:
    import warnings

    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.host.machine import host_capabilities
    from thintact_sdk.host.roofline import measure_sgemm_gflops

    caps = host_capabilities()
    profile = load_profile(args.profile)
    sgemm = measure_sgemm_gflops(1, 1024, 1024, 1024)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        decoder, how = _decoder_choice(profile, args.remeasure)
    choice = getattr(decoder, "backend_choice", None)
    out: dict[str, Any] = {
        "host": caps.as_dict(), "sgemm_gflops": round(sgemm, 1), "profile": profile.name,
        "decoder": getattr(decoder, "name", type(decoder).__name__), "decoder_source": how,
        "backend": None if choice is None else {
            "chosen": choice.chosen, "measured_ms": choice.measured_ms, "psnr_cost_db": choice.psnr_cost_db,
            "not_candidates": choice.unavailable, "from_cache": choice.from_cache, "note": choice.note},
        "warnings": [str(w.message) for w in caught],
    }
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    for line in caps.lines():
        print(line)
    print(f"float32 GEMM (numpy, 1024³): {sgemm:.0f} GFLOP/s measured now")
    print(f"decoder of {profile.name}: {out['decoder']} ({how})")
    print(f"backend: {choice.summary() if choice is not None else 'fixed by the decoder (not measured)'}")
    for w in out["warnings"]:
        print(f"warning: {w}")
    return 0
