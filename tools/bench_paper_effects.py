#!/usr/bin/env python
"""Time and peak memory of simulating each effect at the paper's device size.

For every single-effect case of ``tools/make_concealed_dataset.py`` (the CONTRACTS §5
vocabulary at the concealed data set's amplitudes) a child process builds the simulator of
the shipped ``thintact-paper`` device (1024×1280 sensor, 400×512 scene) with that effect and
simulates 12 random frames; it reports the kernel build time, the 12-frame simulation time
(OpenBLAS on one thread, as
the diagnosis runs it) and its own peak resident memory (``VmHWM``, :mod:`peak_memory`: a child's
``ru_maxrss`` starts at its parent's peak), or the
``ThinTactError`` with which the simulator refuses a kernel that does not fit.

Usage::

    python tools/bench_paper_effects.py [--effects refraction diffraction] [--frames 12]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
sys.path.insert(0, sys.argv[3])
from peak_memory import own_peak_gib
import thintact_sdk  # noqa: F401  (tunes OpenBLAS before numpy loads)
import numpy as np
from thintact_sdk.errors import ThinTactError
from thintact_sdk.simulation.simulator import Simulator
from thintact_sdk.formats.profiles import load_profile
physics, frames = json.loads(sys.argv[1]), int(sys.argv[2])
prof = load_profile("thintact-paper").with_physics(physics)
out = {}
t0 = time.perf_counter()
try:
    sim = Simulator(prof)
    sim.kernel
    t1 = time.perf_counter()
    x = np.random.default_rng(0).random((frames, prof.scene.rows, prof.scene.cols, 3))
    sim.predict_dn(x, 1000.0)
    t2 = time.perf_counter()
    out = {"build_s": round(t1 - t0, 1), "simulate_s": round(t2 - t1, 1),
           "terms": sim.info().get("terms")}
except ThinTactError as e:
    out = {"refused": str(e), "after_s": round(time.perf_counter() - t0, 1)}
out["peak_rss_gib"] = round(own_peak_gib(), 2)
print(json.dumps(out))
"""


def single_effect_cases() -> dict[str, dict]:
    """The concealed data set's single-effect cases (``{case: physics}``)."""
    sys.path.insert(0, str(REPO / "tools"))
    from make_concealed_dataset import CASES

    return {k: v["physics"] for k, v in CASES.items()
            if len(v["physics"]) == 1 and not v.get("subnoise") and not v.get("defects")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--effects", nargs="*", help="case names (default: every single effect)")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per effect")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args(argv)
    cases = {"baseline": {}} | single_effect_cases()
    names = args.effects or list(cases)
    rows = []
    for name in names:
        try:
            proc = subprocess.run([sys.executable, "-c", CHILD, json.dumps(cases[name]), str(args.frames),
                                   str(REPO / "tools")],
                                  capture_output=True, text=True, timeout=args.timeout, check=False,
                                  env=os.environ | {"OPENBLAS_NUM_THREADS": "1"})
            row = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.returncode == 0 else \
                {"failed": f"exit {proc.returncode}: {proc.stderr.strip().splitlines()[-1:]}"}
        except subprocess.TimeoutExpired:
            row = {"failed": f"over {args.timeout:g} s"}
        row = {"case": name, "physics": cases[name]} | row
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
