"""``thintact calibrate-import`` / ``calibrate-export``: system matrices calibrated elsewhere.

    thintact calibrate-import MATRICES.(npz|mat) --profile P --out CAL [--recording REC]
    thintact calibrate-export CAL --out MATRICES.(npz|mat)

The library is :func:`thintact_sdk.calibration.matrices_bundle.import_calibration`; this module
parses and prints.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from thintact_sdk.apps.cli.argtypes import non_negative_int, positive_float
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output, file_input


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate-import",
        help="make a calibration bundle from Po/Qo/Pc/Qc or FlatCam Phi_L/Phi_R (.npz or .mat)",
        description="Imports externally calibrated separable system matrices (shapes checked "
        "against the profile), trains the joint filter on them and chooses tau and the decoder on "
        "the validation frames of --recording (else on simulated scenes).",
    )
    p.add_argument("matrices", type=Path, metavar="MATRICES", help=".npz or MATLAB .mat file")
    p.add_argument("--profile", required=True, help="profile name or file")
    p.add_argument("--out", required=True, type=Path, help="bundle directory to write")
    p.add_argument("--recording", type=Path, help="recording whose validation scenes choose tau")
    p.add_argument("--tau", type=positive_float, help="Tikhonov tau in DN², > 0 (no selection)")
    p.add_argument("--filter-steps", type=non_negative_int, default=100,
                   help="Adam steps of the filter training, >= 0")
    add_force_argument(p, "the bundle into an existing non-empty --out")
    p.set_defaults(func=run_import)
    e = sub.add_parser("calibrate-export", help="write a bundle's Po, Qo, Pc, Qc as .npz or MATLAB .mat")
    e.add_argument("calibration", type=Path, metavar="CAL", help="calibration bundle directory")
    e.add_argument("--out", required=True, type=Path, help="file to write (.npz or .mat)")
    add_force_argument(e, "over an existing --out file")
    e.set_defaults(func=run_export)


def run_import(args: argparse.Namespace) -> int:
    from thintact_sdk.calibration.matrices_bundle import import_calibration
    from thintact_sdk.calibration.pipeline import CalibrationOptions
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.formats.recording import Recording

    claim_output(args.out, "directory", force=args.force,
                 inputs=(args.matrices, args.recording, file_input(args.profile)))
    profile = load_profile(args.profile)
    sm, bundle = import_calibration(
        args.matrices, profile, args.out,
        CalibrationOptions(tau=args.tau, filter_steps=args.filter_steps),
        Recording(args.recording) if args.recording else None)
    print(f"imported {sm.meta['model']} matrices from {args.matrices}")
    print_bundle(bundle, args.out)
    return 0


def print_bundle(bundle: Any, out: Path) -> None:
    """The line naming the bundle written at ``out``: its decoder, τ and how τ was chosen."""
    from thintact_sdk.calibration.validation import default_decoder

    sel = bundle.meta["metrics"].get("tau_selection", {})
    print(f"calibration bundle: {out} (decoder {bundle.meta.get('decoder') or default_decoder()}, "
          f"tau {bundle.tau:.4g} DN², {sel.get('criterion')})")


def run_export(args: argparse.Namespace) -> int:
    from thintact_sdk.formats.matrices import export_matrices
    from thintact_sdk.reconstruction.bundle import CalibrationBundle

    claim_output(args.out, "file", force=args.force, inputs=(args.calibration,))
    bundle = CalibrationBundle.load(args.calibration)
    print(f"written: {export_matrices(bundle.system_matrices, args.out)}")
    return 0
