"""Roofline ratio of ``t2s-closed-form`` (numpy float32, paper operator), unbinned and
binned 2 × 2, for two source trees in alternating rounds (same load for both).

Each round runs one short child process per tree (``--base`` and this checkout, in
alternating order), which builds the decoders, measures the float32 GEMM rate at the
largest product shape and times ``decode(frame, black_level_dn)`` (unbinned: the measurement;
binned: the already-binned frame a Sensor hands a decoder declaring ``input = "binned"``, and
the unbinned frame binned by the decoder) with two kernel threads and with one. Prints one JSON object: per tree,
per case, the median frame time and roofline ratio (frame time / GEMM FLOPs at the GEMM rate
measured in the same child), and the per-round ratios new / base. Usage::

    git archive <commit> | tar -x -C /tmp/base
    python tools/bench_closed_form_ab.py --base /tmp/base [--rounds 4] [--frames 8]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

CHILD = r'''
import contextlib, json, os, sys, time
import numpy as np
from thintact_sdk.reconstruction.decoders import ArrayBackend, T2SClosedFormDecoder
from thintact_sdk.reconstruction.decoders.sensor_binning import SensorBinnedDecoder, bin_frame, bin_system_matrices
from thintact_sdk.algorithms import SystemMatrices, coding_power
from thintact_sdk.pixels.bayer import planar_frame
from thintact_sdk.host.compute_threads import single_threaded_kernels
from thintact_sdk.reconstruction.direct_generation import direct_system_matrices
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.host.roofline import measure_sgemm_gflops

frames = int(sys.argv[1])
profile = load_profile("thintact-paper")
po, qo, pc, qc = direct_system_matrices(np.asarray(profile.mask.phi, float), profile)
c = 3
stack = lambda a: np.repeat(np.asarray(a, np.float32)[None], c, 0)
sm = SystemMatrices(stack(po), stack(qo), stack(pc), stack(qc))
tau = 0.3 * coding_power(sm)
full = T2SClosedFormDecoder(sm, tau, ArrayBackend("numpy", "float32"))
inner = T2SClosedFormDecoder(bin_system_matrices(sm), tau / 4, ArrayBackend("numpy", "float32"))
binned = SensorBinnedDecoder(inner, sm.sensor_shape, c)
(r, s), (n, _) = sm.sensor_shape, sm.scene_shape
frame = planar_frame(r, s, c)
frame[...] = np.random.default_rng(0).integers(64, 4000, (r, s, c))
small = bin_frame(frame).copy()
raw = lambda d: getattr(d, "decode_raw", d.decode)  # a base tree from before the one entry point
cases = {"unbinned": (lambda: raw(full)(frame, 64.0), full.gemm_flops()),
         "bin2_binned_input": (lambda: raw(inner)(small, 64.0), inner.gemm_flops()),
         "bin2_from_full_frame": (lambda: raw(binned)(frame, 64.0), inner.gemm_flops())}
out = {}
for threads in ("2", "1"):
    ctx = single_threaded_kernels() if threads == "1" else contextlib.nullcontext()
    with ctx:
        gf = measure_sgemm_gflops(c, n, r, s)
        for name, (fn, flops) in cases.items():
            fn(); fn()
            ts = []
            for _ in range(frames):
                t0 = time.perf_counter(); fn(); ts.append(time.perf_counter() - t0)
            ms = float(np.median(ts)) * 1e3
            out[f"{name} {threads}t"] = {"ms": ms, "sgemm_gflops": gf, "roofline": ms / (flops / (gf * 1e9) * 1e3)}
print(json.dumps(out))
'''


def _env(tree: Path) -> dict[str, str]:
    paths = [str(tree)] + [str(d) for d in sorted((tree / "plugins").iterdir()) if d.is_dir()]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", type=Path, required=True, help="source tree of the baseline")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--frames", type=int, default=8)
    args = ap.parse_args()
    trees = {"base": args.base.resolve(), "new": Path(__file__).resolve().parents[1]}
    runs: dict[str, list[dict[str, Any]]] = {"base": [], "new": []}
    loads = [os.getloadavg()[0]]
    for k in range(args.rounds):
        for name in (("base", "new") if k % 2 == 0 else ("new", "base")):
            res = subprocess.run([sys.executable, "-c", CHILD, str(args.frames)], env=_env(trees[name]),
                                 capture_output=True, text=True, check=True)
            runs[name].append(json.loads(res.stdout.strip().splitlines()[-1]))
        loads.append(os.getloadavg()[0])
    out: dict[str, Any] = {"load_average_1min": [round(v, 2) for v in loads]}
    for case in runs["new"][0]:
        row: dict[str, Any] = {}
        for name in ("base", "new"):
            ms = sorted(r[case]["ms"] for r in runs[name])
            rl = sorted(r[case]["roofline"] for r in runs[name])
            row[name] = {"ms_median": round(ms[len(ms) // 2], 2), "roofline_median": round(rl[len(rl) // 2], 3),
                         "ms": [round(r[case]["ms"], 2) for r in runs[name]]}
        ratios = sorted(n[case]["ms"] / b[case]["ms"] for n, b in zip(runs["new"], runs["base"], strict=True))
        row["new_over_base_per_round"] = [round(v, 3) for v in ratios]
        out[case] = row
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
