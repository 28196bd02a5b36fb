"""``thintact simulate``: scenes → simulated sensor images (irradiance units or noisy DN)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from thintact_sdk.apps.cli.argtypes import positive_float, seed
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output, file_input
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.recording import SCENE_TOLERANCE


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


def _load_scenes(path: Path) -> np.ndarray:
    if not path.is_file():
        raise ThinTactError(f"scenes file not found: {path}")
    from thintact_sdk.formats.safe_arrays import (
        read_npy,  # header first: no pickle, no huge allocation
    )

    x = read_npy(path, what="scenes", kinds="uif")
    if not isinstance(x, np.ndarray) or x.dtype.kind not in "uif":
        kind = x.dtype if isinstance(x, np.ndarray) else type(x).__name__
        raise ThinTactError(f"scenes {path}: dtype {kind} is not a number array")
    if x.ndim == 3:
        x = x[None]
    if x.ndim != 4:
        raise ThinTactError(f"scenes {path} must be F×N×M×C or N×M×C, got shape {x.shape}")
    if x.shape[0] == 0:
        raise ThinTactError(f"scenes {path} holds no scene (shape {x.shape})")
    x = np.asarray(x, dtype=float)
    bad = ~np.isfinite(x) | (x < 0) | (x > 1.0 + SCENE_TOLERANCE)
    if bad.any():
        f = int(np.argwhere(bad)[0][0])
        raise ThinTactError(f"scenes {path}: scene {f} holds values outside [0, 1] (NaN/Inf "
                            "included); scenes are display values in [0, 1]")
    return x


def run(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.simulation.noise import signal_to_dn
    from thintact_sdk.simulation.simulator import Simulator

    out_path = claim_output(args.out, "file", force=args.force,
                            inputs=(args.scenes, file_input(args.profile)))
    profile = load_profile(args.profile)
    scenes = _load_scenes(args.scenes)
    want = (profile.scene.rows, profile.scene.cols, len(profile.sensor.channels))
    if scenes.shape[1:3] == want[:2] and scenes.shape[3] in (1, 3) and scenes.shape[3] != want[2]:
        from thintact_sdk.reconstruction.filter_training import scene_for_channels

        # what the LCD shows (RGB or grey) as this sensor's channels: mono, R/Gr/Gb/B
        scenes = np.stack([scene_for_channels(x, want[2]) for x in scenes])
    if scenes.shape[1:] != want:
        raise ThinTactError(
            f"scenes have shape {scenes.shape[1:]} per frame but profile {profile.name!r} "
            f"needs N×M×C = {want}"
        )
    sim = Simulator(profile)
    out = np.empty((scenes.shape[0], profile.sensor.rows, profile.sensor.cols, want[2]))
    rng = np.random.default_rng(args.seed)
    gain = None
    if args.noise:
        gain = args.gain if args.gain is not None else sim.reference_gain()
        print(f"gain: {gain:.6g} DN per simulator unit")
    level = sim.physics.get("saturation", {}).get("level_dn")
    with Progress(transient=True) as progress:
        task = progress.add_task("simulating", total=scenes.shape[0])
        for f in range(scenes.shape[0]):
            if gain is None:
                out[f] = sim.forward(scenes[f])
            else:
                sig = sim.predict_signal_dn(scenes[f], gain)
                out[f] = signal_to_dn(sig, profile.noise, rng, saturation_dn=level)
            progress.advance(task)
    if not np.isfinite(out).all():
        raise ThinTactError(f"the simulation of {args.scenes} gave NaN/Inf values; nothing written")
    out_path.parent.mkdir(parents=True, exist_ok=True)
    with open(out_path, "wb") as stream:  # exactly the named file (np.save would add .npy)
        np.save(stream, out)
    print(f"wrote {out_path} ({out.shape[0]} frames, {'DN' if args.noise else 'irradiance'})")
    return 0
