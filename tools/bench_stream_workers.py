"""Streamed tactile frames/s and latency with 1 or N decode workers, in the same run.

Runs ``thintact bench tactile``'s latency section (raw Bayer → TactileFrame on the paper
device, camera at 30 fps) once per worker count (``THINTACT_DECODE_WORKERS``), with the
backend the selection chooses on this host and, with ``--float32``, with CPU bfloat16 left
out of the candidates (as on a host without native bfloat16). ``--decoder`` names the decoder
(e.g. ``t2s-closed-form``) and ``--bundle`` a calibration bundle directory for it; without a
bundle the decoder runs on an in-memory bundle of the directly generated matrices (without
``--decoder`` either: flatcam). Prints one JSON object with the host, the decoder and the
backend the selection chose. Usage::

    .venv/bin/python tools/bench_stream_workers.py [--workers 1 2] [--float32] [--frames 20]
        [--decoder t2s-closed-form] [--bundle DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--profile", default="thintact-paper")
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--float32", action="store_true", help="leave CPU bfloat16 out of the candidates")
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--decoder", help="decoder plugin (default: the profile's, or flatcam without a bundle)")
    p.add_argument("--bundle", type=Path, help="calibration bundle directory for the decoder")
    args = p.parse_args()

    import thintact_sdk.reconstruction.decoders.components as thintact_decoders
    from thintact_sdk.apps.benchmarks.tactile_accuracy import latency
    from thintact_sdk.host.machine import host_capabilities, machine_summary

    if args.float32:
        thintact_decoders.host_capabilities = lambda: replace(host_capabilities(), native_bf16=False)
    results: dict[str, Any] = {"host": machine_summary(), "load_before": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as cache:
        os.environ.setdefault("THINTACT_CACHE_DIR", cache)  # a given one keeps the backend selection
        for workers in args.workers:
            os.environ["THINTACT_DECODE_WORKERS"] = str(workers)
            out: dict[str, Any] = {}
            latency(argparse.Namespace(latency_profile=args.profile, decoder=args.decoder, seed=0,
                                       latency_frames=args.frames, latency_bundle=args.bundle), out)
            s = out["stream"]
            key = f"workers={workers}"
            key += f" (run {sum(k.startswith(key) for k in results) + 1})" if key in results else ""
            results[key] = {
                "fps": round(s["fps"], 1), "latency_p50_ms": round(s["latency_p50_ms"], 1),
                "latency_p99_ms": round(s["latency_p99_ms"], 1),
                "p99_over_p50": round(s["latency_p99_ms"] / s["latency_p50_ms"], 2),
                "waited_ms_max": round(s["waited_ms_max"], 1),
                "decode_workers": s.get("decode_workers"),
                "load_1min": round(os.getloadavg()[0], 2),
                "decoder": out["latency_ms"].get("decoder"),
                "single_frame_median_ms": {k: round(v, 1) for k, v in out["latency_ms"]["median"].items()}}
    results["load_after"] = os.getloadavg()[0]
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
