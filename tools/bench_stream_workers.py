"""Streamed tactile frames/s and latency with 1 or N decode workers, in the same run.

Runs ``thintact bench tactile``'s latency section (raw Bayer → TactileFrame on the paper
device, camera at 30 fps) once per worker count (``THINTACT_DECODE_WORKERS``), with the
backend the selection chooses on this host and, with ``--float32``, with CPU bfloat16 left
out of the candidates (as on a host without native bfloat16). Prints one JSON object with
the host. Usage::

    .venv/bin/python tools/bench_stream_workers.py [--workers 1 2] [--float32] [--frames 20]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from dataclasses import replace
from typing import Any


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--profile", default="thintact-paper")
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--float32", action="store_true", help="leave CPU bfloat16 out of the candidates")
    p.add_argument("--frames", type=int, default=20)
    args = p.parse_args()

    import thintact_decoders

    from thintact_sdk.benchmarks.tactile import latency
    from thintact_sdk.machine import host_capabilities, machine_summary

    if args.float32:
        thintact_decoders.host_capabilities = lambda: replace(host_capabilities(), native_bf16=False)
    results: dict[str, Any] = {"host": machine_summary(), "load_before": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as cache:
        os.environ["THINTACT_CACHE_DIR"] = cache
        for workers in args.workers:
            os.environ["THINTACT_DECODE_WORKERS"] = str(workers)
            out: dict[str, Any] = {}
            latency(argparse.Namespace(latency_profile=args.profile, decoder=None, seed=0,
                                       latency_frames=args.frames), out)
            s = out["stream"]
            results[f"workers={workers}"] = {
                "fps": round(s["fps"], 1), "latency_p50_ms": round(s["latency_p50_ms"], 1),
                "latency_p99_ms": round(s["latency_p99_ms"], 1),
                "single_frame_median_ms": {k: round(v, 1) for k, v in out["latency_ms"]["median"].items()}}
    results["load_after"] = os.getloadavg()[0]
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
