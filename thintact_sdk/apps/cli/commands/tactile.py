"""``thintact tactile import | depth | evaluate``: press packs, depth maps and ball-press figures.

The libraries: :func:`thintact_sdk.tactile.calibration.press_pack.import_folder`,
:func:`thintact_sdk.tactile.interpretation.depth_maps.write_depth_maps` and
:func:`thintact_sdk.tactile.calibration.press_pack.evaluate_pack`; this module parses and prints.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from thintact_sdk.apps.cli.argtypes import GRADIENT_MODELS, int_range, positive_float, positive_int
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output
from thintact_sdk.formats.safe_yaml import dump_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "tactile",
        help="press packs (import a folder of images), depth maps, ball-press evaluation",
        description="Tools for real tactile data: import a folder of reference + press images "
        "as a press pack, write depth maps of a pack or a recording, evaluate ball presses of "
        "known radius (calibrate on some presses, measure the others).",
    )
    tsub = p.add_subparsers(dest="tactile_command", metavar="SUBCOMMAND", required=True)

    imp = tsub.add_parser(
        "import", help="a folder of reference + press images → a press pack (.npz)",
        description="Read a no-contact reference image and ball-press images (JPEG, PNG, ...) "
        "from a folder and write a press pack (.npz, no pickle: imgs, f0, names, mm_per_px, "
        "ball_radius_mm).")
    imp.add_argument("folder", type=Path, help="folder holding the images")
    imp.add_argument("--out", required=True, help="press pack to write (.npz)")
    imp.add_argument("--reference", default="ref.*",
                     help="glob of the no-contact image in the folder (default ref.*)")
    imp.add_argument("--presses", default="sample_*",
                     help="glob of the press images (default sample_*)")
    imp.add_argument("--colour-order", choices=("rgb", "bgr"), default="rgb",
                     help="rgb: ordinary colour files; bgr: red and blue swapped in the files")
    imp.add_argument("--crop", default="0,0,0,0",
                     help="pixels removed from top,bottom,left,right (default 0,0,0,0)")
    imp.add_argument("--mm-per-px", type=positive_float, help="gel mm per image pixel")
    imp.add_argument("--ball-radius-mm", type=positive_float, help="ball radius in mm")
    add_force_argument(imp, "over an existing pack")
    imp.set_defaults(func=run_import)

    dep = tsub.add_parser(
        "depth", help="depth maps (npy + PNG) and per-frame contact/peak/force JSON",
        description="Interpret every press of a pack (against its reference) or every frame of "
        "a recording and write depth_NNNN.npy (float32 mm), depth_NNNN.png (16-bit, µm) and "
        "frames.json (contact, contact area, peak depth, force per frame).")
    src = dep.add_mutually_exclusive_group(required=True)
    src.add_argument("--pack", type=Path, help="press pack (.npz)")
    src.add_argument("--recording", type=Path, help="recording (thintact-recording/1)")
    dep.add_argument("--profile", help="device profile (recording: required; pack: optional)")
    dep.add_argument("--lut", type=Path, help="tactile LUT (.npz) for a pack without a profile")
    dep.add_argument("--mm-per-px", type=positive_float,
                     help="pack pixel size (default: the pack's)")
    dep.add_argument("--out", required=True, help="output folder")
    dep.add_argument("--quiet", action="store_true", help="no progress lines")
    add_force_argument(dep, "into an existing non-empty folder")
    dep.set_defaults(func=run_depth)

    ev = tsub.add_parser(
        "evaluate", help="calibrate on some ball presses of a pack, measure the others",
        description="Annotation-free: calibrate the gradient model on the --train presses "
        "(default the even ones) from the images and the ball radius, reconstruct the others "
        "and report the fitted sphere radius, contact radius against sqrt(2Rd - d^2), depth "
        "and slope RMS against the ball fitted with its radius fixed (and against the "
        "annotated circles when the pack has them).")
    ev.add_argument("pack", type=Path, help="press pack (.npz)")
    ev.add_argument("--ball-radius-mm", type=positive_float,
                    help="ball radius (default: the pack's)")
    ev.add_argument("--mm-per-px", type=positive_float, help="pixel size (default: the pack's)")
    ev.add_argument("--train", help="comma-separated training presses (default: even ones)")
    ev.add_argument("--model", choices=GRADIENT_MODELS, default="auto",
                    help="gradient model: auto (the table, the per-pixel network or the "
                    "convolutional network, chosen on validation presses; default), lut, mlp, cnn")
    ev.add_argument("--ball-model", choices=("auto", "rigid", "sink-in"), default="auto",
                    help="shape of the training presses in the gel, as calibrate-tactile's: auto (the "
                    "rigid cap or a sink-in skirt fitted to the gel, whichever reconstructs held-out "
                    "training presses as the ball; default), rigid, sink-in")
    ev.add_argument("--bins", type=int_range(4, 256), default=24, help="LUT nodes per axis")
    ev.add_argument("--mlp-steps", type=positive_int, default=1500,
                    help="per-pixel network training steps")
    ev.add_argument("--cnn-steps", type=positive_int, default=3000,
                    help="convolutional network training steps")
    ev.add_argument("--json", dest="json_out", help="write every figure to this JSON file")
    ev.add_argument("--quiet", action="store_true", help="no progress lines")
    add_force_argument(ev, "over an existing --json")
    ev.set_defaults(func=run_evaluate)


def run_import(args: argparse.Namespace) -> int:
    from thintact_sdk.tactile.calibration.press_pack import import_folder, parse_crop

    out = claim_output(args.out, "file", force=args.force, inputs=(args.folder,))
    if out.suffix != ".npz":  # numpy would add one, past the check above
        from thintact_sdk.errors import OutputError

        raise OutputError(f"--out {out} must name a .npz file (a press pack)")
    pack = import_folder(args.folder, args.reference, args.presses, args.colour_order,
                         parse_crop(args.crop), args.mm_per_px, args.ball_radius_mm)
    path = pack.save(out)
    h, w = pack.reference.shape[:2]
    print(f"{len(pack.images)} presses of {w}×{h} px ({args.colour_order}, crop "
          f"{args.crop}; reference {pack.meta['reference']}) → {path}")
    return 0


def _number(value: Any, what: str, option: str) -> float:
    from thintact_sdk.errors import ThinTactError

    if value is None:
        raise ThinTactError(f"the pack does not state its {what}: give {option}")
    return float(value)


def run_depth(args: argparse.Namespace) -> int:
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.host.progress import stage_reporter
    from thintact_sdk.tactile.interpretation.depth_maps import write_depth_maps

    out = claim_output(args.out, "directory", force=args.force, inputs=[args.pack, args.recording, args.lut])
    with stage_reporter(args.quiet) as say:
        maps = write_depth_maps(
            out, pack=args.pack, recording=args.recording, lut=args.lut, mm_per_px=args.mm_per_px,
            profile=None if args.profile is None else load_profile(args.profile), progress=say)
    print(f"{len(maps.frames)} depth maps ({maps.in_contact} in contact) in {out}; per-frame figures in "
          f"{maps.frames_json.name}")
    return 0


def run_evaluate(args: argparse.Namespace) -> int:
    from thintact_sdk.errors import ThinTactError
    from thintact_sdk.host.progress import stage_reporter
    from thintact_sdk.tactile.calibration.press_pack import evaluate_pack, load_press_pack

    json_out = None
    if args.json_out is not None:
        json_out = claim_output(args.json_out, "file", force=args.force, inputs=(args.pack,))
    pack = load_press_pack(args.pack)
    radius = _number(args.ball_radius_mm or pack.ball_radius_mm, "ball radius",
                     "--ball-radius-mm")
    mm = _number(args.mm_per_px or pack.mm_per_px, "pixel size", "--mm-per-px")
    train = None
    if args.train is not None:
        try:
            train = [int(t) for t in args.train.split(",") if t.strip()]
        except ValueError:
            raise ThinTactError(f"--train {args.train!r}: comma-separated press numbers") from None
    with stage_reporter(args.quiet) as say:
        res = evaluate_pack(pack, radius, mm, train, args.model, args.bins,
                            mlp_steps=args.mlp_steps, stage=say, ball_model=args.ball_model,
                            cnn_options={"steps": args.cnn_steps})
    _print_evaluation(res, radius)
    if json_out is not None:
        res.pop("lut")
        json_out.write_text(dump_json(res) + "\n")
        print(f"wrote {json_out}")
    return 0


def _print_evaluation(res: dict[str, Any], radius: float) -> None:
    """The calibration's warnings, the models used and the held-out figures of ``evaluate_pack``."""
    from thintact_sdk.tactile.interpretation.gradient_model import describe_validation

    s = res["summary"]
    for entry in res["press_report"]:
        for w in entry["warnings"]:
            print(f"calibration press {res['train'][entry['press']]}: {w}")
    bm = res.get("ball_model")
    if bm:
        skirt = f", skirt length {bm['skirt_length_mm']:.2f} mm" if bm.get("skirt_length_mm") else ""
        how = f" ({bm['chosen_by']})" if bm.get("chosen_by") else ""
        print(f"ball model: {bm['model']}{skirt}{how}")
    if res.get("contact_rim_mm") is not None:
        print(f"contact regions grown by {res['contact_rim_mm']:.3f} mm (the calibration's rim)")
    val = res["validation"]
    chosen = res["gradient_model"]
    if val:
        print(f"gradient model: {chosen} (validation slope RMS: {describe_validation(val)})")
    else:
        print(f"gradient model: {chosen}")
    print(f"{s['presses']} test presses, ball radius {radius:g} mm:")
    print(f"  fitted sphere radius  median {s['sphere_radius_median_mm']:.2f} mm "
          f"({s['sphere_radius_median_mm'] / radius - 1:+.0%}), middle half "
          f"{s['sphere_radius_q25_mm']:.2f}-{s['sphere_radius_q75_mm']:.2f} mm")
    if s["contact_ratio_median"] is not None:
        skirt = (f" (the region deeper than the contact threshold, skirt included: "
                 f"{s['skirt_ratio_median']:.2f})" if s.get("skirt_ratio_median") else "")
        print(f"  contact radius / sqrt(2Rd-d^2)  median {s['contact_ratio_median']:.2f}{skirt}")
        if s.get("contact_ratio_taught_median") is not None:
            print("    the calibration's ball model pressed as deep reads "
                  f"{s['contact_ratio_taught_median']:.2f} through the same measure (a perfect "
                  "reconstruction of the taught shape)")
    gentle = (f"; {s['slope_rms_gentle']:.3f} where the ball's slope is under 45 deg"
              if s.get("slope_rms_gentle") is not None else "")
    print(f"  depth RMS {s['depth_rms_mm']:.3f} mm, slope RMS {s['slope_rms']:.3f} "
          f"(flat {s['slope_rms_flat']:.3f}{gentle}) inside the contact, against the ball "
          "fitted with its radius fixed")
    if "annotated_depth_rms_mm" in s and None in (s["annotated_depth_rms_mm"], s.get("annotated_slope_rms"),
                                                 s.get("annotated_press_mean_mm")):
        print("  against the annotated circles: none could be evaluated (a radius of 0, or a "
              "circle outside the frame)")
    elif "annotated_depth_rms_mm" in s:
        print(f"  against the annotated circles: depth RMS {s['annotated_depth_rms_mm']:.3f} mm "
              f"(their mean press depth {s['annotated_press_mean_mm']:.2f} mm), slope RMS "
              f"{s['annotated_slope_rms']:.3f}")
    print(f"  edge presses {s['edge_presses']}"
          + (f", fitted radius vs interior {s['edge_radius_vs_interior_median']:+.0%}"
             if "edge_radius_vs_interior_median" in s else ""))
