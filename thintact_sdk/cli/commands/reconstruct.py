"""``thintact reconstruct RECORDING --calibration CAL --out DIR``: one scene estimate per frame.

Each frame's measurement (raw DN) minus the dark level (the recording's dark frames, i.e.
all-zero scenes, when it has any, else the profile's black level), normalised to the
bundle's exposure when both are known, goes through the decoder; the estimate is written
as ``DIR/<measurement file stem>.npy`` (``N × M × 3`` float32, display units).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reconstruct", help="reconstruct every frame of a recording with a calibration")
    p.add_argument("recording", metavar="RECORDING", help="thintact-recording/1 directory")
    p.add_argument("--calibration", required=True, metavar="CAL", help="calibration bundle directory")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory for the .npy estimates")
    p.add_argument("--decoder", help="decoder plugin (default: the one the calibration recommends, "
                   "calibration.json 'decoder', else thintact-noniterative)")
    p.add_argument("--tau", type=float, help="override the bundle's Tikhonov tau (DN², chosen by the "
                   "calibration on the unit's own frames)")
    p.add_argument("--dark", choices=["auto", "black"], default="auto",
                   help="auto: subtract the recording's dark frames (all-zero scenes) when it has "
                   "any, else the black level; black: always the profile's black level")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from thintact_sdk.calibration.collect import dark_level, frame_exposure_us
    from thintact_sdk.calibration.validation import make_decoder
    from thintact_sdk.imaging.calibration_bundle import CalibrationBundle
    from thintact_sdk.recording import Recording

    console = Console(stderr=True)
    rec = Recording(args.recording)
    profile = rec.profile
    bundle = CalibrationBundle.load(args.calibration)
    bundle.check_shapes(profile)
    if not bundle.matches_profile(profile):
        console.print(
            f"[yellow]warning: the calibration was made for profile {bundle.meta.get('profile')!r} with "
            "other physics fields than this recording's profile[/yellow]"
        )
    settings = {} if args.tau is None else {"tau": args.tau}
    decoder_name = args.decoder or str(bundle.meta.get("decoder") or "thintact-noniterative")
    decoder = make_decoder(profile, bundle, decoder_name, **settings)
    ref_exposure = bundle.meta.get("exposure_us")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    dark, dark_source = dark_level(rec, use_dark_frames=args.dark == "auto")
    dark32 = dark.astype(np.float32)
    console.print(f"[dim]subtracting {dark_source}[/dim]")
    with Progress(TextColumn("reconstructing"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=console, disable=args.no_progress) as prog:
        task = prog.add_task("frames", total=len(rec))
        for i, fr in enumerate(rec.frames):
            meas = np.asarray(rec.measurement(i), np.float32)
            if meas.ndim == 2:
                meas = meas[..., None]
            signal = meas - dark32[..., : meas.shape[2]]
            exposure = frame_exposure_us(rec, i)
            if isinstance(ref_exposure, int | float) and exposure is not None:
                signal *= np.float32(ref_exposure / exposure)
            estimate = np.asarray(decoder.decode(signal), np.float32)
            np.save(out / f"{Path(fr.measurement).stem}.npy", estimate)
            prog.advance(task)
    print(f"{len(rec)} reconstructions written to {out}")
    return 0
