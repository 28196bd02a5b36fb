"""``thintact reconstruct RECORDING --calibration CAL --out DIR``: one scene estimate per frame.

Each frame's measurement (raw DN) minus the dark level (the recording's dark frames, i.e.
all-zero scenes, when it has any, else the profile's black level), normalised to the
bundle's exposure when both are known, goes through the decoder; the estimate is written
as ``DIR/<measurement file stem>.npy`` (``N × M × 3`` float32, display units).

Every frame is checked before anything is written (a NaN, Inf or negative measurement is
refused naming the frame), ``DIR`` must be new or empty unless ``--force``, and an estimate
that is not finite is an error, never a silent all-NaN file.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from thintact_sdk.apps.cli.argtypes import positive_float
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output
from thintact_sdk.errors import RecordingError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reconstruct", help="reconstruct every frame of a recording with a calibration")
    p.add_argument("recording", metavar="RECORDING", help="thintact-recording/1 directory")
    p.add_argument("--calibration", required=True, metavar="CAL", help="calibration bundle directory")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory for the .npy estimates")
    p.add_argument("--decoder", help="decoder (default: the one the calibration recommends, "
                   "calibration.json 'decoder', else the calibration's default: the first decoder "
                   "declaring the trait calibration-candidate)")
    p.add_argument("--tau", type=positive_float, help="override the bundle's Tikhonov tau (DN², > 0; "
                   "default: the calibration's, chosen on the unit's own frames)")
    p.add_argument("--dark", choices=["auto", "black"], default="auto",
                   help="auto: subtract the recording's dark frames (all-zero scenes) when it has "
                   "any, else the black level; black: always the profile's black level")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_force_argument(p, "into an existing non-empty --out")
    p.set_defaults(func=run)


def _check_unique_outputs(rec: Any) -> None:
    """Refuse frames whose estimates would land in the same ``DIR/<stem>.npy`` file."""
    seen: dict[str, int] = {}
    for i, fr in enumerate(rec.frames):
        stem = Path(fr.measurement).stem
        if stem in seen:
            raise RecordingError(
                f"recording {rec.root}: frames {seen[stem]} and {i} would both be written as "
                f"{stem}.npy (their measurement files share a name); one would overwrite the other"
            )
        seen[stem] = i


def run(args: argparse.Namespace) -> int:
    from thintact_sdk.calibration.collect import dark_level, frame_exposure_us
    from thintact_sdk.calibration.validation import make_decoder
    from thintact_sdk.errors import CalibrationError
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.reconstruction.bundle import CalibrationBundle

    console = Console(stderr=True)
    out = claim_output(args.out, "directory", force=args.force, inputs=(args.recording, args.calibration))
    rec = Recording(args.recording)
    _check_unique_outputs(rec)
    rec.check_frames()
    profile = rec.profile
    bundle = CalibrationBundle.load(args.calibration)
    bundle.check_shapes(profile)
    if not bundle.matches_profile(profile):
        console.print(
            f"[yellow]warning: the calibration was made for profile {bundle.meta.get('profile')!r} with "
            "other physics fields than this recording's profile[/yellow]"
        )
    settings = {} if args.tau is None else {"tau": args.tau}
    decoder_name = args.decoder or bundle.meta.get("decoder") or None
    decoder = make_decoder(profile, bundle, None if decoder_name is None else str(decoder_name), **settings)
    ref_exposure = bundle.meta.get("exposure_us")
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
            if not np.isfinite(estimate).all():
                raise CalibrationError(
                    f"frame {i} ({fr.label or fr.measurement}): the decoder returned NaN/Inf "
                    f"values (measurement {float(meas.min()):.4g}..{float(meas.max()):.4g} DN, "
                    f"calibration {args.calibration}); nothing was written for it"
                )
            np.save(out / f"{Path(fr.measurement).stem}.npy", estimate)
            prog.advance(task)
    print(f"{len(rec)} reconstructions written to {out}")
    return 0
