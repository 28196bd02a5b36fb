"""``thintact reconstruct RECORDING --calibration CAL --out DIR``: one scene estimate per frame.

Parses, claims ``DIR`` (new or empty unless ``--force``), calls
:func:`thintact_sdk.calibration.estimates.reconstruct_recording` (the dark level, the exposure
normalisation, the checks and the ``DIR/<measurement file stem>.npy`` files are described
there) and prints.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from thintact_sdk.apps.cli.argtypes import positive_float
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output


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


def run(args: argparse.Namespace) -> int:
    from thintact_sdk.calibration.estimates import reconstruct_recording
    from thintact_sdk.formats.recording import Recording

    console = Console(stderr=True)
    out = claim_output(args.out, "directory", force=args.force, inputs=(args.recording, args.calibration))
    rec = Recording(args.recording)
    with contextlib.ExitStack() as stack:
        steps: list[Callable[[], None]] = []

        def started(run: Any) -> None:  # everything checked: say what runs, then the bar
            if run.profile_warning:
                console.print(f"[yellow]warning: {run.profile_warning}[/yellow]")
            console.print(f"[dim]subtracting {run.dark_source}[/dim]")
            prog = stack.enter_context(Progress(
                TextColumn("reconstructing"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                console=console, disable=args.no_progress))
            task = prog.add_task("frames", total=len(rec))
            steps.append(lambda: prog.advance(task))

        result = reconstruct_recording(rec, args.calibration, out, decoder=args.decoder, tau=args.tau,
                                       dark_frames=args.dark == "auto", on_start=started,
                                       advance=lambda: steps[0]())
    print(f"{len(result.written)} reconstructions written to {out}")
    return 0
