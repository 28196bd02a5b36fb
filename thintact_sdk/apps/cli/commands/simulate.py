"""``thintact simulate``: scenes → simulated sensor images (irradiance units or noisy DN).

The library is :func:`thintact_sdk.simulation.scene_batch.simulate_scenes`; this module parses
and writes the ``.npy``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np

from thintact_sdk.apps.cli.argtypes import positive_float, seed
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output, file_input


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate sensor images of scenes with a profile's physics",
        description=(
            "Simulate F scenes (F×N×M×C float .npy, display values; RGB or grey scenes are "
            "shown to a monochrome or R/Gr/Gb/B sensor as its channels) with a device profile. "
            "Writes F×R×S×C float64: noiseless irradiance in simulator units, or with --noise "
            "raw DN (black level included) with Poisson + read noise, rounded and clipped."
        ),
    )
    p.add_argument("--profile", required=True, help="profile name or file")
    p.add_argument("--scenes", required=True, type=Path, help="F×N×M×C (or N×M×C) .npy")
    p.add_argument("--out", required=True, help="output .npy")
    p.add_argument("--noise", action="store_true", help="output noisy DN instead of irradiance")
    p.add_argument("--seed", type=seed, default=0, help="noise seed (with --noise), 0..2**63-1")
    p.add_argument("--gain", type=positive_float, default=None,
                   help="DN per simulator unit (with --noise); default puts the brightest "
                        "all-white pixel at 60%% of (saturation - black)")
    add_force_argument(p, "over an existing --out file")
    p.set_defaults(func=run)


def _reporter(say: Callable[[str], None], what: str, unit: str) -> Callable[[int, int], None]:
    """``progress(done, total)`` as a message each whole percent (at most 101 lines)."""
    shown = [-1]

    def report(done: int, total: int) -> None:
        pct = 100 * done // max(total, 1)
        if pct != shown[0]:
            shown[0] = pct
            say(f"{what}: {pct} % ({done}/{total} {unit})")
    return report


def run(args: argparse.Namespace) -> int:
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.host.progress import stage_reporter
    from thintact_sdk.simulation.scene_batch import simulate_scenes

    out_path = claim_output(args.out, "file", force=args.force,
                            inputs=(args.scenes, file_input(args.profile)))
    profile = load_profile(args.profile)
    with stage_reporter() as say:  # a status line on a terminal, timestamped lines elsewhere
        made = simulate_scenes(profile, args.scenes, noise=args.noise, seed=args.seed, gain=args.gain,
                               progress=_reporter(say, "simulating frames", "frames"),
                               build_progress=_reporter(say, "building the imaging kernel", "steps"))
    if made.gain is not None:
        print(f"gain: {made.gain:.6g} DN per simulator unit")
    out_path.parent.mkdir(parents=True, exist_ok=True)
    with open(out_path, "wb") as stream:  # exactly the named file (np.save would add .npy)
        np.save(stream, made.frames)
    print(f"wrote {out_path} ({made.frames.shape[0]} frames, {'DN' if args.noise else 'irradiance'})")
    return 0
