"""``thintact calibrate-tactile --profile P``: calibrate and store the photometric-stereo LUT."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from thintact_sdk.apps.cli.argtypes import GRADIENT_MODELS, int_range, positive_float, positive_int
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output, file_input


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate-tactile",
        help="calibrate the depth LUT from ball presses (virtual sensor, recording or live)",
        description=(
            "Press a ball of known radius into the membrane and store the colour→slope LUT "
            "with the device (calibrations/<device>/tactile/lut.npz + lut.json under "
            "$THINTACT_CALIBRATION_PATH's first directory, else ./calibrations; an existing "
            "LUT is only replaced with --force). A virtual "
            "sensor is pressed by the tactile simulator; --recording uses a recording whose "
            "'reference' (or first) frame has no contact; otherwise the live camera is used "
            "and you are prompted for each press."
        ),
    )
    p.add_argument("--profile", required=True, help="profile name or file")
    p.add_argument("--recording", type=Path, help="recording of ball presses (thintact-recording/1)")
    p.add_argument("--presses", type=positive_int, default=12, help="ball presses (virtual, live), >= 1")
    p.add_argument("--ball-radius-mm", type=positive_float, default=1.5,
                   help="calibration ball radius in mm (paper: 3 mm ball → 1.5)")
    p.add_argument("--bins", type=int_range(4, 256), default=32, help="LUT nodes per colour axis (4..256)")
    p.add_argument("--model", choices=GRADIENT_MODELS, default="auto",
                   help="gradient model for ball-model presses (recording, live): auto (the "
                   "table, the per-pixel colour + position network or the convolutional "
                   "network, whichever predicts held-out validation presses best; default), "
                   "lut, mlp, cnn. Virtual sensors: lut")
    p.add_argument("--ball-model", choices=("auto", "rigid", "sink-in"), default="auto",
                   help="shape the ball presses into the gel (recording, live): auto (the rigid "
                   "cap or the cap with a sink-in skirt whose length is fitted to the gel, "
                   "whichever reconstructs held-out calibration presses as the ball; "
                   "default), rigid, sink-in. Virtual sensors: not used")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--out", help="LUT file (default: the device's folder under "
                   "$THINTACT_CALIBRATION_PATH or ./calibrations, never the checkout's)")
    add_force_argument(p, "over an existing LUT")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from thintact_sdk.device.cameras import camera_is_simulated
    from thintact_sdk.device.sensor import Sensor
    from thintact_sdk.errors import OutputError
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.calibration import device as dc
    from thintact_sdk.tactile.calibration.store import device_lut_path, user_calibrations_root

    profile = load_profile(args.profile)
    inputs = (args.recording, file_input(args.profile))
    if args.out is not None:
        target = claim_output(args.out, "file", force=args.force, inputs=inputs)
        if target.suffix != ".npz":
            raise OutputError(f"--out {target} must name a .npz file (its .json goes beside it)")
    else:
        target = claim_output(device_lut_path(profile, user_calibrations_root()), "file",
                              force=args.force, option="the device LUT", inputs=inputs)
    claim_output(target.with_suffix(".json"), "file", force=args.force, option="the LUT's metadata",
                 inputs=inputs)
    virtual = camera_is_simulated(profile)
    from thintact_sdk.host.progress import stage_reporter

    if args.recording is not None:  # no prompts: plain progress lines, terminal or not
        sensor = Sensor(profile)
        with stage_reporter(args.quiet) as say:
            lut = dc.calibrate_recording(
                sensor, args.recording, args.ball_radius_mm, args.bins,
                progress=lambda done, total: say(f"press image {done}/{total} reconstructed"),
                model=args.model, stage=say, ball_model=args.ball_model)
        return _report(lut, profile, target)
    with Progress(transient=True, disable=args.quiet) as bar:
        task = bar.add_task("ball presses", total=args.presses)

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        with Sensor(profile) as sensor:
            if virtual:
                lut = dc.calibrate_virtual(sensor, args.presses, args.ball_radius_mm,
                                           bins=args.bins, progress=progress)
            else:
                bar.stop()
                lut = dc.calibrate_live(sensor, args.presses, args.ball_radius_mm,
                                        bins=args.bins, progress=progress,
                                        model=args.model, stage=print,
                                        ball_model=args.ball_model)
    return _report(lut, profile, target)


def _rim_words(rim: float | None) -> str:
    """Where the contact measure reads one press's contact, against the model's rim."""
    if rim is None:
        return ""
    return f", contact read {abs(rim):.2f} mm {'inside' if rim >= 0 else 'outside'} it"


def _report(lut: Any, profile: Any, target: Path) -> int:
    """Save the LUT, print the per-press report (warnings first) and the summary."""
    from thintact_sdk.tactile.interpretation.gradient_model import describe_validation

    for entry in lut.meta.get("press_report", []):
        print(f"press {entry['press']}: circle at (row {entry['centre_rc'][0]:.1f}, col "
              f"{entry['centre_rc'][1]:.1f}) px, radius {entry['circle_radius_mm']:.2f} mm; "
              f"fitted press {entry['press_mm']:.2f} mm, contact radius "
              f"{entry['contact_radius_mm']:.2f} mm"
              + _rim_words(entry.get("contact_rim_mm")))
        for w in entry["warnings"]:
            print(f"  warning: {w}")
    bm = lut.meta.get("ball_model")
    if bm and bm.get("chosen_by") == "validation":
        def name(m: dict[str, Any]) -> str:
            return "rigid" if m["model"] == "rigid" else f"sink-in L={m['skirt_length_mm']:g} mm"

        scores = ", ".join(f"{name(c)} {c['score']:.3f}" for c in bm["candidates"])
        print(f"ball model {name(bm)}: validation presses {bm['validation_presses']}, "
              f"score |sphere/R - 1|, |contact ratio - 1|: {scores}")
    rim = lut.meta.get("contact_rim_mm")
    if rim is not None:
        print(f"contact regions grown by {rim:.3f} mm: how far inside the rim of the taught "
              "presses the curvature's sign change reads (median over the presses)")
    val = lut.meta.get("validation")
    if val:
        print(f"gradient model {lut.meta.get('gradient_model')}: validation presses "
              f"{val['presses']}, slope RMS {describe_validation(val)}")
    path = lut.save(target)
    filled = int((lut.counts > 1e-3).sum())
    print(f"tactile LUT for {profile.name!r}: {lut.meta.get('presses')} presses, "
          f"{lut.meta.get('calibration_pixels')} pixels, {filled} of {lut.bins**3} nodes "
          f"filled, slopes from {lut.meta.get('slopes_from')}")
    print(f"saved {path} (+ {path.with_suffix('.json').name})")
    return 0
