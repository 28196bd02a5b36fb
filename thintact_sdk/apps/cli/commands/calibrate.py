"""``thintact calibrate``: the LCD calibration wizard, or a calibration from a recording.

    thintact calibrate --profile thintact-paper            # wizard (resumes an unfinished run)
    thintact calibrate --from-recording REC --out CAL       # offline, same solve

The library is :mod:`thintact_sdk.calibration.sessions` (``calibrate_from_recording``,
``calibrate_with_wizard``); this module parses, shows progress and prints the outcome.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from thintact_sdk.apps.cli.argtypes import (
    KEY_VALUE_HELP,
    key_value,
    key_values,
    non_negative_int,
    positive_float,
    positive_int,
)
from thintact_sdk.apps.cli.output_path import (
    add_force_argument,
    check_not_an_input,
    claim_output,
    file_input,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate the system matrices: LCD wizard (--profile) or from a recording",
        description="Slit-scan calibration of the T2S system matrices (paper §D, Alg. 1-3), "
        "joint-filter training and validation; writes calibrations/<device>/<timestamp>/.",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--profile", metavar="P", help="run the wizard for this profile (name or file)")
    src.add_argument("--from-recording", metavar="DIR", help="calibrate from a thintact-recording/1 directory")
    p.add_argument("--out", metavar="DIR", help="bundle directory (default calibrations/<device>/<timestamp>)")
    p.add_argument("--restart", action="store_true", help="wizard: start a new capture instead of resuming")
    p.add_argument("--frames", type=positive_int,
                   help="frames averaged per pattern, >= 1 (default 100; 8 for virtual cameras)")
    p.add_argument("--flush", type=non_negative_int, default=1,
                   help="frames dropped after each pattern change (default 1)")
    p.add_argument("--method", choices=["lsq", "paper"], default="lsq",
                   help="lsq: joint least squares per slit (default); paper: Algorithm 1 verbatim")
    p.add_argument("--max-iter", type=positive_int, default=50, help="refinement iterations (Algorithm 3)")
    p.add_argument("--tau", type=positive_float,
                   help="Tikhonov tau in DN², > 0 (default: cross-validated on the recording's "
                   "validation scenes)")
    p.add_argument("--frame-gains", choices=["off", "auto", "on"], default="off",
                   help="per-slit-frame gains from the white frame (unrecorded exposure or "
                   "brightness drift); only for well-averaged recordings (noise leaks in)")
    p.add_argument("--filter-steps", type=non_negative_int, default=0,
                   help="Adam steps of the joint-filter training after its closed form (default 0: "
                   "the closed form only; see docs/calibration.md, 'Filter steps')")
    p.add_argument("--camera-set", action="append", default=[], metavar="KEY=VALUE", type=key_value,
                   help="override a camera setting (" + KEY_VALUE_HELP + ")")
    p.add_argument("--no-registration-check", action="store_true",
                   help="wizard: continue even if the registration check fails")
    p.add_argument("--compare-reference", action="store_true",
                   help="virtual devices: compare with the simulator's two-term fit")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_force_argument(p, "the bundle into an existing non-empty --out (an unfinished wizard "
                       "capture there is resumed without it)")
    p.set_defaults(func=run)


def _progress(disabled: bool, console: Console) -> Progress:
    return Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
        TextColumn("{task.fields[label]}"), TimeElapsedColumn(), TextColumn("left"),
        TimeRemainingColumn(), console=console, disable=disabled,
    )


def run(args: argparse.Namespace) -> int:
    from thintact_sdk.calibration.pipeline import CalibrationOptions

    console = Console(stderr=True)
    options = CalibrationOptions(
        method=args.method, max_iter=args.max_iter, tau=args.tau, frame_gains=args.frame_gains,
        filter_steps=args.filter_steps,
    )
    if args.from_recording:
        outcome = _offline(args, options, console)
    else:
        outcome = _wizard(args, options, console)
    m = outcome.bundle.meta["metrics"]
    verdict = "PASS" if outcome.passed else "FAIL"
    sel = m.get("tau_selection", {})
    print(f"calibration bundle: {outcome.path}")
    print(f"decoder {sel.get('decoder')}, tau {sel.get('tau')} DN² ({sel.get('criterion')})")
    per_channel = sel.get("channel_tau", {}).get(sel.get("decoder"))
    if per_channel:
        print(f"  tau per channel: {', '.join(f'{t:.4g}' for t in per_channel)} DN² (better held out than one tau)")
    prior = sel.get("scene_prior", {}).get(sel.get("decoder"))
    if prior:
        print(f"  scene prior: DCT weights (1 + k/{prior['k0']:g})^{prior['alpha']:g}, held out "
              f"{prior['held_out_mean_psnr_db']:.2f} dB vs {prior['plain_held_out_mean_psnr_db']:.2f} dB plain Tikhonov")
    print(f"validation (held out): mean PSNR {m['mean_psnr_db']:.2f} dB, mean SSIM {m['mean_ssim']:.3f} "
          f"-> {verdict}")
    for f in m.get("verdict", {}).get("failures", []):
        print(f"  FAIL {f['what']}: {f['detail']}\n       fix: {f['fix']}")
    for s in m["solve"]:
        print(f"  channel {s['channel']}: {s['iterations']} iterations, "
              f"{'converged' if s['converged'] else 'NOT converged'}, relative residual {s['relative_residual']:.3e}")
    if "reference" in m:
        errs = ", ".join(f"{e:.4f}" for e in m["reference"]["operator_error"])
        print(f"  vs simulator two-term fit: operator error per channel {errs}")
    print(f"report: {outcome.path / 'report.html'}")
    return 0 if outcome.passed else 1


def _offline(args: argparse.Namespace, options: Any, console: Console) -> Any:
    from thintact_sdk.calibration.sessions import calibrate_from_recording
    from thintact_sdk.errors import CalibrationError

    if args.out is None:
        raise CalibrationError("--from-recording needs --out DIR (the bundle directory to write)")
    out = claim_output(args.out, "directory", force=args.force, inputs=(args.from_recording,))
    prog, on_frame = _lazy_bar(args.no_progress, console, "slit frames")
    try:
        return calibrate_from_recording(
            args.from_recording, out, options, compare_reference=args.compare_reference,
            progress=on_frame, status=lambda s: prog.console.print(f"[dim]{s}[/dim]"))
    finally:
        prog.stop()


def _lazy_bar(disabled: bool, console: Console, what: str) -> tuple[Progress, Any]:
    """A progress bar that appears at its first step (an input refused before any work is
    one error line, no bar) and its step callback ``(done, total, label)``."""
    prog = _progress(disabled, console)
    task = prog.add_task(what, total=None, label="")

    def on_step(done: int, total: int, label: str) -> None:
        if not prog.live.is_started:
            prog.start()
        prog.update(task, completed=done, total=total, label=label)

    return prog, on_step


def _wizard_out(args: argparse.Namespace) -> Path:
    """The wizard's ``--out``: an unfinished capture there is resumed (the documented resume,
    unless ``--restart``); anything else that exists needs ``--force``."""
    from thintact_sdk.calibration.wizard import CAPTURE_DIR
    from thintact_sdk.reconstruction.bundle import META_FILE

    if not args.out.strip():
        return claim_output(args.out, "directory")  # refuses the empty path
    inputs = (file_input(args.profile),)
    out = Path(args.out)
    unfinished = (out / CAPTURE_DIR / "manifest.json").is_file() and not (out / META_FILE).is_file()
    if unfinished and not args.restart:
        check_not_an_input(out, inputs)
        return out
    return claim_output(args.out, "directory", force=args.force, inputs=inputs)


def _wizard(args: argparse.Namespace, options: Any, console: Console) -> Any:
    from thintact_sdk.calibration.sessions import calibrate_with_wizard, wizard_bundle_dir
    from thintact_sdk.formats.profiles import load_profile

    profile = load_profile(args.profile)
    out = _wizard_out(args) if args.out is not None else None
    bundle_dir, resumed = wizard_bundle_dir(profile, out, restart=args.restart)
    if resumed:
        console.print(f"resuming the unfinished calibration in {bundle_dir} (--restart for a new one)")
    prog, on_step = _lazy_bar(args.no_progress, console, "patterns")
    try:
        return calibrate_with_wizard(
            profile, bundle_dir, options, frames=args.frames, flush=args.flush,
            check_registration=not args.no_registration_check, camera_settings=key_values(args.camera_set),
            compare_reference=args.compare_reference, progress=on_step,
            status=lambda s: prog.console.print(f"[dim]{s}[/dim]"))
    finally:
        prog.stop()
