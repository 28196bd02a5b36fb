"""``thintact diagnose RECORDING --out DIR``: where and how a recording departs from the
simulation, which effects of the vocabulary are missing, fitted (CONTRACTS §6)."""

from __future__ import annotations

import argparse
import sys
import time

from thintact_sdk.apps.cli.argtypes import non_negative_float, non_negative_int, positive_float
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="compare a recording with the simulation, name and fit the missing physics",
        description=__doc__,
    )
    p.add_argument("recording", metavar="RECORDING", help="thintact-recording/1 directory")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--time-budget", type=positive_float, default=75.0, metavar="S",
                   help="seconds allowed for naming effects (default 75; the whole run stays under 120 s)")
    p.add_argument("--sys-frac", type=non_negative_float, default=1e-3, metavar="F",
                   help="systematic-error allowance, relative (default 0.001)")
    p.add_argument("--max-effects", type=non_negative_int, default=4, metavar="K",
                   help="accept at most K effects (default 4)")
    p.add_argument("--bin", type=non_negative_int, default=0, metavar="B",
                   help="diagnose the sensor binned B×B (exact for the imaging model; 0: automatic, "
                        "binning sensors above 128×160 pixels, 1: never)")
    p.add_argument("--no-unbinned-check", dest="unbinned_check", action="store_false",
                   help="after a binned diagnosis, skip evaluating the fit on the unbinned recording (and the unbinned stage, which names effects finer than a block there)")
    p.add_argument("--no-coarse-angle", dest="coarse_angle", action="store_false",
                   help="when the mask angle cannot be screened on the binned data (the paper's device), do not fit "
                        "it on coarser blocks afterwards (that stage costs minutes at large angles)")
    p.add_argument("--png", action="store_true", help="also write the figures as DIR/figures/*.png")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_force_argument(p, "into an existing non-empty --out")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from thintact_sdk.diagnosis.imaging import RecordingOptions, diagnose_recording
    from thintact_sdk.diagnosis.imaging.outputs import write_outputs

    out = claim_output(args.out, "directory", force=args.force, inputs=(args.recording,))
    con = Console(stderr=True, quiet=args.quiet)
    t0 = time.perf_counter()
    opts = RecordingOptions(sys_frac=args.sys_frac, time_budget_s=args.time_budget, max_effects=args.max_effects,
                            bin_factor=args.bin, unbinned_check=args.unbinned_check,
                            coarse_angle_check=args.coarse_angle)
    with con.status("diagnosing...") as status:
        d = diagnose_recording(args.recording, opts, progress=status.update, log=con.print,
                               warn=lambda m: print(f"warning: {m}", file=sys.stderr))
    rep = d.report
    paths = write_outputs(d, out, png=args.png)
    print(f"baseline: rms {rep['baseline']['rms_dn']:.2f} DN, chi2/dof {rep['baseline']['chi2_per_dof']:.3f} "
          f"(noise rms {rep['noise_rms_dn']:.2f} DN)")
    for f in rep["findings"]:
        alt = f" (or: {', '.join(f['alternatives'])})" if f["alternatives"] else ""
        print(f"  + {f['effect']}{alt}: {f['params']} -> chi2/dof {f['chi2_per_dof_after']:.3f}")
    print(f"final: rms {rep['final']['rms_dn']:.2f} DN, chi2/dof {rep['final']['chi2_per_dof']:.3f}")
    if "full_size" in rep and "final" in rep["full_size"]:
        ff = rep["full_size"]["final"]
        print(f"unbinned: final rms {ff['rms_dn']:.2f} DN, chi2/dof {ff['chi2_per_dof']:.3f}")
    elif "full_size" in rep:
        print(f"unbinned: the whole sensor not evaluated ({rep['full_size']['not_evaluated']})")
        win = rep["full_size"]["windows"]
        if "not_evaluated" in win:
            print(f"  on windows: not evaluated either ({win['not_evaluated']})")
        else:
            print(f"  on {win['where']}: rms {win['rms_dn']:.2f} DN, chi2/dof {win['chi2_per_dof']:.3f} "
                  f"({win['excess_z']:+.1f} standard deviations from the noise)")
    coarse_rep = rep.get("binned", {}).get("coarse_angle")
    if coarse_rep:
        print(f"mask angle: {coarse_rep['summary']}")
    low = rep.get("below_floor", [])
    for b in low[:3]:
        print(f"  under the amplitude floor ({b['data']}): {b['effect']} {b['params']} would lower chi2 by "
              f"{b['dchi2']:.0f} but changes the prediction by {b['amplitude_fraction']:.1e} of the signal "
              f"(floor {b['floor']:.0e}): not named")
    if len(low) > 3:
        print(f"  ({len(low) - 3} more under the floor in report.json below_floor)")
    stage_rep = rep.get("binned", {}).get("unbinned_stage")
    if stage_rep and stage_rep["ran"]:
        print(f"unbinned stage: {stage_rep['summary']}")
    if rep["unexplained"]["significant"]:
        print(f"unexplained: {rep['unexplained']['summary']}")
    print(f"wrote {paths['report']}, {paths['fitted_profile']}, {paths['html']} "
          f"in {time.perf_counter() - t0:.1f} s ({int(d.timing_s.get('simulations', 0))} simulations)")
    return 0
