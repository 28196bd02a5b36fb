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


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("doctor", help="host capabilities and the decoder backend chosen on this host")
    p.add_argument("--profile", default="thintact-paper",
                   help="device profile whose decoder is checked (default thintact-paper)")
    p.add_argument("--remeasure", action="store_true",
                   help="measure the backends again (e.g. on a quiet machine) and replace this host's "
                        "cached choice")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from thintact_sdk.apps.benchmarks.host_report import host_report
    from thintact_sdk.formats.profiles import load_profile

    profile = load_profile(args.profile)
    report = host_report(profile, args.remeasure)
    out, choice = report.data, report.backend_choice
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    for line in report.capabilities.lines():
        print(line)
    print(f"float32 GEMM (numpy, 1024³): {report.sgemm_gflops:.0f} GFLOP/s measured now")
    print(f"decoder of {profile.name}: {out['decoder']} ({out['decoder_source']})")
    print(f"backend: {choice.summary() if choice is not None else 'fixed by the decoder (not measured)'}")
    for w in out["warnings"]:
        print(f"warning: {w}")
    return 0
