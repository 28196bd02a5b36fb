#!/usr/bin/env python
"""Write a calibration bundle for a virtual profile from the simulator.

Usage::

    .venv/bin/python tools/make_virtual_calibration.py virtual-mini [--out thintact_sdk/data/calibrations] [--steps 60]

The bundle (two-term fit of the simulator, trained joint filter, τ, validation metrics) goes
to ``<out>/<profile>/<YYYYmmddTHHMMSS>/``; every file is float32 and compressed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rich.console import Console
from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.reconstruction.bundle import timestamp_name
from thintact_sdk.reconstruction.virtual_bundle import (
    VirtualCalibrationOptions,
    make_virtual_bundle,
)

MAX_FILE_BYTES = 2 * 1024 * 1024


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("profile", help="profile name or file (virtual-mini, virtual-finger, ...)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "thintact_sdk" / "data"
                                         / "calibrations"),
                    help="root directory of calibration bundles (default: the packaged ones, "
                         "thintact_sdk/data/calibrations)")
    ap.add_argument("--steps", type=int, default=60, help="Adam steps of filter training")
    ap.add_argument("--scenes", type=int, default=48, help="number of training scenes")
    ap.add_argument("--rank", type=int, default=4, help="rank of the spatial filter Φs")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    console = Console(stderr=True)
    try:
        profile = load_profile(args.profile)
        opts = VirtualCalibrationOptions(training_count=args.scenes, steps=args.steps,
                                         phi_s_rank=args.rank, seed=args.seed)
        with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                      console=console) as prog:
            task = prog.add_task(f"{profile.name}: starting")
            bundle = make_virtual_bundle(
                profile, opts, progress=lambda msg: prog.update(task, description=f"{profile.name}: {msg}")
            )
        out = bundle.save(Path(args.out) / profile.name / timestamp_name())
    except ThinTactError as err:
        console.print(f"error: {err}")
        return 2
    big = [f for f in out.iterdir() if f.stat().st_size > MAX_FILE_BYTES]
    print(f"wrote {out}")
    print(json.dumps({k: bundle.meta[k] for k in ("tau", "metrics")}, indent=1))
    if big:
        console.print(f"warning: files over 2 MB: {', '.join(f.name for f in big)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
