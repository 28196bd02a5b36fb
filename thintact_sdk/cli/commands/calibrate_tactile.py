"""``thintact calibrate-tactile --profile P``: calibrate and store the photometric-stereo LUT."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate-tactile",
        help="calibrate the depth LUT from ball presses (virtual sensor, recording or live)",
        description=(
            "Press a ball of known radius into the membrane and store the colour→slope LUT "
            "with the device (calibrations/<device>/tactile/lut.npz + lut.json). A virtual "
            "sensor is pressed by the tactile simulator; --recording uses a recording whose "
            "'reference' (or first) frame has no contact; otherwise the live camera is used "
            "and you are prompted for each press."
        ),
    )
    p.add_argument("--profile", required=True, help="profile name or file")
    p.add_argument("--recording", type=Path, help="recording of ball presses (thintact-recording/1)")
    p.add_argument("--presses", type=int, default=12, help="ball presses (virtual, live)")
    p.add_argument("--ball-radius-mm", type=float, default=1.5,
                   help="calibration ball radius in mm (paper: 3 mm ball → 1.5)")
    p.add_argument("--bins", type=int, default=32, help="LUT nodes per colour axis")
    p.add_argument("--out", type=Path, help="LUT file (default: the device's calibrations folder)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from thintact_sdk.errors import ThinTactError
    from thintact_sdk.profile import load_profile
    from thintact_sdk.sensor import VIRTUAL_CAMERAS, Sensor
    from thintact_sdk.tactile import device_calibration as dc
    from thintact_sdk.tactile.store import save_device_lut

    if args.presses < 1 or args.bins < 4 or args.ball_radius_mm <= 0:
        raise ThinTactError("--presses must be ≥ 1, --bins ≥ 4 and --ball-radius-mm > 0")
    profile = load_profile(args.profile)
    virtual = profile.camera is not None and profile.camera.plugin in VIRTUAL_CAMERAS
    with Progress(transient=True) as bar:
        task = bar.add_task("ball presses", total=args.presses)

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        if args.recording is not None:
            sensor = Sensor(profile)
            lut = dc.calibrate_recording(sensor, args.recording, args.ball_radius_mm, args.bins,
                                         progress=progress)
        else:
            with Sensor(profile) as sensor:
                if virtual:
                    lut = dc.calibrate_virtual(sensor, args.presses, args.ball_radius_mm,
                                               bins=args.bins, progress=progress)
                else:
                    bar.stop()
                    lut = dc.calibrate_live(sensor, args.presses, args.ball_radius_mm,
                                            bins=args.bins, progress=progress)
    path = lut.save(args.out) if args.out is not None else save_device_lut(lut, profile)
    filled = int((lut.counts > 1e-3).sum())
    print(f"tactile LUT for {profile.name!r}: {lut.meta.get('presses')} presses, "
          f"{lut.meta.get('calibration_pixels')} pixels, {filled} of {lut.bins**3} nodes "
          f"filled, slopes from {lut.meta.get('slopes_from')}")
    print(f"saved {path} (+ {path.with_suffix('.json').name})")
    return 0
