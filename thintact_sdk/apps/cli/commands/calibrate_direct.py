"""``thintact calibrate-direct --profile P --recording REC --out CAL``: a bundle from the
profile's design by direct generation (no slit frames).

The profile should already hold the mask's pose (``thintact calibrate pose``). The system
matrices come from :meth:`thintact_sdk.reconstruction.t2s.SystemMatrices.direct`, in DN with the
scale the recording's white (flat) frame fixes; the rest (joint filter training, τ and the
decoder chosen on the recording's validation frames, the bundle) is the path of
``calibrate-import``. The library is
:func:`thintact_sdk.calibration.matrices_bundle.direct_calibration`; this module parses and prints.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from thintact_sdk.apps.cli.argtypes import non_negative_int, positive_float
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output, file_input


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate-direct",
        help="make a calibration bundle from the profile's mask design and pose (direct generation)",
        description="Generates Po, Qo, Pc, Qc from the profile's phi, phi_rows, geometry and pose "
        "(physics, as 'calibrate pose' wrote them), scaled to DN by the recording's white frame "
        "(minus its dark frames), trains the joint filter and chooses tau and the decoder on the "
        "recording's validation frames (frames with a known scene that is neither dark nor a slit). "
        "Cross-validation needs two folds of distinct scenes; with fewer the choice falls back to "
        "simulated scenes and a warning says how many there were. Also 'thintact calibrate direct'.",
    )
    p.add_argument("--profile", required=True, help="profile name or file (with the mask's pose)")
    p.add_argument("--recording", required=True, type=Path, metavar="REC",
                   help="recording with a white (flat) frame; its validation frames choose tau")
    p.add_argument("--out", required=True, type=Path, help="bundle directory to write")
    p.add_argument("--scale-dn", type=positive_float, metavar="DN",
                   help="DN above black of a white scene through a fully open mask (default: from "
                   "the recording's white frame)")
    p.add_argument("--tau", type=positive_float, help="Tikhonov tau in DN², > 0 (no selection)")
    p.add_argument("--filter-steps", type=non_negative_int, default=100,
                   help="Adam steps of the filter training, >= 0")
    add_force_argument(p, "the bundle into an existing non-empty --out")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    from thintact_sdk.apps.cli.commands.calibrate_matrices import print_bundle
    from thintact_sdk.calibration.matrices_bundle import direct_calibration
    from thintact_sdk.calibration.pipeline import CalibrationOptions
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.formats.recording import Recording

    claim_output(args.out, "directory", force=args.force, inputs=(args.recording, file_input(args.profile)))
    profile = load_profile(args.profile)
    made = direct_calibration(
        profile, Recording(args.recording), args.out,
        CalibrationOptions(tau=args.tau, filter_steps=args.filter_steps), args.scale_dn,
        stage=lambda line: print(line, file=sys.stderr, flush=True))
    print(f"direct generation: {profile.mask.K} cells, scale {made.scale_dn:.4g} DN ({made.scale_source})")
    angle = float(made.matrices.meta.get("unmodelled_angle_deg") or 0.0)
    if angle:
        print(f"note: the mask's residual turn of {angle:.3g} deg is held only as its separable mean")
    print_bundle(made.bundle, args.out)
    if args.tau is None and not made.chosen_on_the_unit:
        criterion = made.bundle.meta.get("metrics", {}).get("tau_selection", {}).get("criterion")
        print(f"warning: {args.recording} has {made.distinct_scenes} distinct validation scene(s) "
              f"({made.validation_frames} frame(s) with a known scene that is neither dark nor a slit); "
              f"choosing tau and the decoder on the unit needs {made.scenes_needed} "
              f"({made.scenes_needed // 2} per fold), so they were chosen by '{criterion}' instead of "
              "on its own frames; record more scenes (a scene=PATH role in 'thintact record import') "
              "to choose them on the unit", file=sys.stderr)
    return 0
