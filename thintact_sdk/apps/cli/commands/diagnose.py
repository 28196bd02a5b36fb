"""``thintact diagnose RECORDING --out DIR``: where and how a recording departs from the
simulation, which effects of the vocabulary are missing, fitted (CONTRACTS §6)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any

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


def _check_finite(report: dict[str, Any]) -> None:
    """Refuse to write a report whose headline figures are NaN/Inf (never a silent NaN)."""
    from thintact_sdk.errors import ThinTactError

    figures = {"noise_rms_dn": report.get("noise_rms_dn")}
    for part in ("baseline", "final"):
        for key in ("rms_dn", "chi2_per_dof"):
            figures[f"{part}.{key}"] = report.get(part, {}).get(key)
    bad = [k for k, v in figures.items() if not (isinstance(v, int | float) and math.isfinite(v))]
    if bad:
        raise ThinTactError(f"the diagnosis gave non-finite {', '.join(bad)} (too few usable "
                            "pixels: saturated or masked?); nothing was written")


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from thintact_sdk.diagnosis.imaging import DiagnoseOptions, diagnose, load_diagnosis_data
    from thintact_sdk.diagnosis.imaging.binning import (
        auto_bin_factor,
        bin_data,
        binned_variance_fn,
        full_size_check,
        screening_limits,
        simulate_float32,
        unbin_hotspots,
        unbinned_amplitude_fn,
    )
    from thintact_sdk.diagnosis.imaging.coarse_angle import CoarseAngleInput
    from thintact_sdk.diagnosis.imaging.engine import known_candidates
    from thintact_sdk.diagnosis.imaging.outputs import write_outputs
    from thintact_sdk.diagnosis.imaging.unbinned import UnbinnedInput
    from thintact_sdk.diagnosis.imaging.window_check import window_check

    out = claim_output(args.out, "directory", force=args.force, inputs=(args.recording,))
    con = Console(stderr=True, quiet=args.quiet)
    t0 = time.perf_counter()
    data = load_diagnosis_data(args.recording)
    con.print(
        f"{data.n_frames} frames with scenes ({data.skipped} without), "
        f"{data.profile.sensor.rows}×{data.profile.sensor.cols} sensor"
    )
    if data.saturated_frames:
        listed = ", ".join(f"{k} ({v:g} DN)" for k, v in list(data.saturated_frames.items())[:5])
        more = f" and {len(data.saturated_frames) - 5} more" if len(data.saturated_frames) > 5 else ""
        print(f"warning: {len(data.saturated_frames)} frame(s) saturated at every pixel: {listed}{more}; "
              "diagnosed as data (report.json saturated_frames)", file=sys.stderr)
    full_data, full_profile = data, data.profile
    b = args.bin or auto_bin_factor(full_profile.sensor.rows, full_profile.sensor.cols)
    if b > 1:
        data = bin_data(data, b)
        con.print(f"diagnosing the sensor binned {b}×{b}: {data.profile.sensor.rows}×"
                  f"{data.profile.sensor.cols} pixels of {data.profile.sensor.pixel_pitch_um:g} um")
    opts = DiagnoseOptions(sys_frac=args.sys_frac, time_budget_s=args.time_budget, max_effects=args.max_effects)
    # at every size: an effect whose kernel family is out of reach is held or dropped, and a
    # finding it could stand behind names it (a wide field of view needs this unbinned too)
    limits = screening_limits(data.profile)
    skipped: dict[str, str] = limits.not_screened
    if skipped:
        opts.candidates = [c for c in known_candidates(data.profile) if c not in limits.dropped]
        opts.held_params = limits.held
    if b > 1:
        opts.fine_amplitude = unbinned_amplitude_fn(full_data, sys_frac=args.sys_frac)
        if args.unbinned_check:
            opts.unbinned = UnbinnedInput(full_data, b, simulate=simulate_float32)
        if args.coarse_angle and "angle_deg" in limits.held.get("mask_misalignment", ()):
            opts.coarse_angle = CoarseAngleInput(full_data, b, simulate=simulate_float32)
    for name, why in skipped.items():
        later = " (fitted on coarser blocks after the selection)" if opts.coarse_angle is not None \
            and name == "mask_misalignment.angle_deg" else ""
        con.print(f"not screened here: {name} ({why}){later}")
    with con.status("diagnosing...") as status:
        d = diagnose(data, variance_fn=binned_variance_fn(b) if b > 1 else None, options=opts,
                     progress=lambda m: status.update(m))
    rep = d.report
    if b > 1:
        unbin_hotspots(rep, b)
        rep["binned"] = {"factor": b, "rows": data.profile.sensor.rows, "cols": data.profile.sensor.cols,
                         "not_screened": skipped}
        if d.unbinned is not None:
            rep["binned"]["unbinned_stage"] = d.unbinned.to_json()
        if d.coarse_angle is not None:
            rep["binned"]["coarse_angle"] = d.coarse_angle.to_json()
            if d.coarse_angle.ran:  # screened after all, on coarser blocks
                skipped.pop("mask_misalignment.angle_deg", None)
        d.fitted_profile = full_profile.with_physics(dict(d.fitted_profile.physics))
        if args.unbinned_check:
            con.print("evaluating the fit on the unbinned recording")
            stage = d.unbinned
            if d.unbinned_skipped:
                con.print("the whole sensor's kernel is refused: checking the fit on windows of it")
                rep["full_size"] = {"not_evaluated": d.unbinned_skipped,
                                    "windows": window_check(full_data, d.selection.values, args.sys_frac).to_json()}
            elif stage is not None and stage.check and not (stage.selection and stage.selection.rounds) \
                    and not stage.refitted and not stage.replaced:
                rep["full_size"] = {"final": dict(stage.check)}  # the stage's own evaluation of this model
            else:
                rep["full_size"] = {"final": full_size_check(full_data, d.selection.values, args.sys_frac)}
                if stage is not None and stage.check:
                    rep["full_size"]["before_unbinned_stage"] = dict(stage.check)
    if b == 1 and skipped:  # beyond CONTRACTS §6, only when there is something to say
        rep["not_screened"] = skipped
    if full_data.saturated_frames:  # CONTRACTS §6 keys otherwise: only present when there are any
        rep["saturated_frames"] = dict(full_data.saturated_frames)
    _check_finite(rep)
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
