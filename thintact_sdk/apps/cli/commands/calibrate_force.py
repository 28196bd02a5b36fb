"""``thintact calibrate-force --profile P --presses PACK.npz --loads LOADS.json``: fit and store
the force gains from presses of known load (:mod:`thintact_sdk.tactile.calibration.force_gains`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output, file_input


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate-force",
        help="fit the force gains from presses of known load (stored beside the tactile LUT)",
        description=(
            "Interpret presses of known load (a press pack: .npz with f0, the unloaded membrane, "
            "and imgs, P presses, on the profile's scene grid) with the device's LUT, fit the "
            "force gains (normal c0, c1 or one scale of them; shear ct from the sheared presses) "
            "and store them as calibrations/<device>/tactile/force.json under "
            "$THINTACT_CALIBRATION_PATH's first directory, else ./calibrations (an existing file "
            "is only replaced with --force). Prints and stores the per-press report (load given, "
            "estimated, error). The loads file is JSON: {\"loads_n\": [Fz or [Fx, Fy, Fz], ...]} "
            "in newtons, one per press."
        ),
    )
    p.add_argument("--profile", required=True, help="profile name or file")
    p.add_argument("--presses", required=True, type=Path, metavar="PACK.npz",
                   help="press pack: f0 (N×M×3) and imgs (P×N×M×3), display units or uint8")
    p.add_argument("--loads", required=True, type=Path, metavar="LOADS.json",
                   help="known loads, one per press, in N")
    p.add_argument("--out", help="force calibration file (.json; default: the device's folder "
                   "under $THINTACT_CALIBRATION_PATH or ./calibrations)")
    add_force_argument(p, "over an existing force calibration")
    p.set_defaults(func=run)


def _fmt(v: float | None) -> str:
    return "    -" if v is None else f"{v:6.3f}"


def run(args: argparse.Namespace) -> int:
    from thintact_sdk.errors import OutputError
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.calibration.force_gains import (
        calibrate_force,
        load_loads,
        load_press_pack,
    )
    from thintact_sdk.tactile.calibration.store import force_calibration_path, lut_for_profile

    profile = load_profile(args.profile)
    inputs = (args.presses, args.loads, file_input(args.profile))
    if args.out is not None:
        target = claim_output(args.out, "file", force=args.force, inputs=inputs)
        if target.suffix != ".json":
            raise OutputError(f"--out {target} must name a .json file")
    else:
        target = claim_output(force_calibration_path(profile), "file", force=args.force,
                              option="the device's force calibration", inputs=inputs)
    f0, imgs = load_press_pack(args.presses, profile)
    loads = load_loads(args.loads, len(imgs))
    cal = calibrate_force(profile, lut_for_profile(profile), f0, imgs, loads)
    print(f"force gains for {profile.name!r} from {len(imgs)} presses (E {cal.youngs_mpa:g} MPa, "
          f"ν {cal.poisson:g}): c0 {cal.normal_gain:.4f}, c1 {cal.normal_fill_gain:.4f} "
          f"({cal.normal_method}), ct {cal.shear_gain:.4f} ({cal.shear_method})")
    print("press  given Fx     Fy     Fz   estimated Fx     Fy     Fz   Fz error  rel")
    for r in cal.rows:
        g, e = r["given_n"], r["estimated_n"]
        print(f"{r['press']:5d}  {_fmt(g[0])} {_fmt(g[1])} {_fmt(g[2])}   {_fmt(e[0])} "
              f"{_fmt(e[1])} {_fmt(e[2])}   {r['normal_error_n']:+7.3f} "
              f"{100 * r['normal_error_rel']:+5.1f} %")
    print(f"normal force RMS error {100 * cal.normal_rms_rel():.1f} %")
    path = cal.save(target)
    print(f"saved {path}")
    return 0
