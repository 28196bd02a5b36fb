"""``thintact calibrate-pose FLAT --profile P --out PROFILE``: the mask's pose from a flat field.

The library is :func:`thintact_sdk.calibration.flat_field.pose_from_flat_field`; this module
parses, prints the estimate and writes the profile.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from thintact_sdk.apps.cli.argtypes import positive_float
from thintact_sdk.apps.cli.output_path import add_force_argument


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate-pose",
        help="estimate the mask's orientation (quarter turns, mirror images), residual rotation, "
        "offset and magnification from a flat field",
        description="Fits the known mask pattern to one uniformly lit capture and writes a profile "
        "whose mask vectors (phi, phi_rows rewritten for a quarter turn or a mirror image: exact, "
        "and the mask stays separable) and physics (mask_misalignment: the residual turn and the "
        "offset; geometry: z) describe where the mask really is; direct generation and the "
        "simulator honour them. A mask turned more than a few degrees away from every quarter turn "
        "is refused: no separable model holds there. Every mounting is scored against random masks; "
        "the runner-up is reported, and an unsure pose (margin or floor not met, the fitted unknown "
        "outside its bounds) exits 3 without writing unless --accept-ambiguous. Large frames are "
        "binned to a working size and the result mapped back. Progress goes to stderr.",
    )
    p.add_argument("flat", type=Path, metavar="FLAT",
                   help="a recording (its all-white frame is used, minus its dark frames) or an "
                   "R×S(×C) .npy of raw DN (minus the profile's black level)")
    p.add_argument("--profile", required=True, help="profile name or file (the nominal design)")
    p.add_argument("--out", required=True, type=Path, help="profile file to write (.json or .yaml)")
    p.add_argument("--unknown", choices=("z", "pitch", "none"), default="z",
                   help="which of the scene-to-mask distance z and the sensor pixel pitch is not known "
                   "and is fitted from the shadow's scale delta*H/(z*p) (default z; 'none': both as the "
                   "profile says)")
    p.add_argument("--bounds", type=positive_float, nargs=2, metavar=("LOW", "HIGH"),
                   help="bounds of the unknown (mm for z, um for the pitch); default z*(1 +- 0.1), "
                   "pitch*(0.8 .. 1.25)")
    p.add_argument("--accept-ambiguous", action="store_true",
                   help="write the profile and exit 0 even when the pose is unsure (the best mounting "
                   "does not beat the runner-up by the margin, the pattern is not clearly found, or "
                   "the unknown left its bounds); otherwise such a pose exits 3 and writes nothing")
    p.add_argument("--report", type=Path, help="also write the full pose report (every mounting's "
                   "score, the runner-up, the verdict) as JSON here")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    add_force_argument(p)
    p.set_defaults(func=run)


def _claim_outputs(args: argparse.Namespace) -> None:
    """``--out`` and ``--report``: new files (or ``--force``), neither an input nor each other."""
    from thintact_sdk.apps.cli.output_path import claim_output, file_input
    from thintact_sdk.errors import OutputError

    inputs = (args.flat, file_input(args.profile))
    claim_output(args.out, "file", force=args.force, inputs=inputs)
    if args.report is not None:
        claim_output(args.report, "file", force=args.force, option="--report", inputs=inputs)
        if args.report.resolve() == args.out.resolve():
            raise OutputError(f"--report {args.report} is the --out profile; name another file")


def run(args: argparse.Namespace) -> int:
    import json
    import sys
    import time

    from thintact_sdk.calibration.flat_field import pose_from_flat_field
    from thintact_sdk.calibration.pose import FLOOR_SIGMA, MARGIN_SIGMA
    from thintact_sdk.formats.profiles import load_profile, write_profile

    _claim_outputs(args)
    profile = load_profile(args.profile)
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"[pose {time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    found = pose_from_flat_field(args.flat, profile, args.unknown,
                                 tuple(args.bounds) if args.bounds else None, progress=progress)
    est = found.estimate
    print(f"flat field: {found.source}")
    o = est.orientation
    rewritten = "" if o == type(o)() else " (phi and phi_rows rewritten as mounted)"
    best = est.hypotheses[0]
    print(f"mask {o.name}{rewritten}; residual rotation {est.angle_deg:+.4f}°; "
          f"shift dx {est.dx_um:+.2f} um, dy {est.dy_um:+.2f} um")
    if est.unknown == "z":
        print(f"scene-to-mask z {est.scene_to_mask_mm:.4f} ± {est.scale_sigma:.4f} mm (fitted; profile "
              f"{profile.geometry.scene_to_mask_mm:g}, bounds {est.bounds[0]:.4g}..{est.bounds[1]:.4g})"  # type: ignore[index]
              )
    elif est.unknown == "pitch":
        print(f"pixel pitch {est.pixel_pitch_um:.5f} ± {est.scale_sigma:.5f} um (fitted; profile "
              f"{profile.sensor.pixel_pitch_um:g}, bounds {est.bounds[0]:.4g}..{est.bounds[1]:.4g}); "  # type: ignore[index]
              f"z {est.scene_to_mask_mm:.4f} mm")
    else:
        print(f"scale not fitted: z {est.scene_to_mask_mm:g} mm, pitch {est.pixel_pitch_um:g} um")
    print(f"shadow cell on the sensor {est.fit['shadow_px_per_cell']:.2f} px; worked on the frame binned "
          f"{int(est.fit['binning'])}×{int(est.fit['binning'])}")
    print(f"score: {best.sigma_x:.1f} (x) and {best.sigma_y:.1f} (y) random-mask spreads above random "
          f"masks (floor {FLOOR_SIGMA:g} each); 2-D relative RMS residual {est.fit['rel_rms']:.4f}")
    if est.runner_up is not None:
        r = est.runner_up
        print(f"runner-up: {r.orientation.name}, {r.sigma:.1f} spreads (best {best.sigma:.1f}; margin "
              f"{est.margin_sigma:.1f}, required {MARGIN_SIGMA:g})")
    else:
        print("runner-up: none (every mounting gives the same mask)")
    for line in est.ambiguities:
        print(f"design ambiguity: {line}")
    if args.report is not None:
        args.report.write_text(json.dumps(est.to_json(), indent=2) + "\n", encoding="utf-8")
        print(f"report written: {args.report}")
    if not est.confident:
        for line in est.problems:
            print(f"UNSURE: {line}", file=sys.stderr)
        print("UNSURE: resolve it with an asymmetric target (a scene or a press at a known corner, "
              "reconstructed with the best and the runner-up pose), a known edge of the mask on the "
              "sensor, a second flat field after a known quarter turn, or a better-known scale "
              "(--unknown, --bounds)", file=sys.stderr)
        if not args.accept_ambiguous:
            print(f"no profile written (pass --accept-ambiguous to write {args.out} anyway)", file=sys.stderr)
            return 3
        print("written anyway (--accept-ambiguous)", file=sys.stderr)
    write_profile(est.apply(profile), args.out)
    print(f"profile written: {args.out}")
    return 0
