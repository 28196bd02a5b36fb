"""``thintact demo``: a press on the built-in virtual sensor, end to end, as one figure.

A simulated 4 mm ball presses the membrane (with a little shear); the virtual camera renders
the lensless measurement through the simulator with the sensor noise model; the sensor
bins, reconstructs and interprets it exactly as it would a real camera's frames. The
figure shows the raw Bayer frame, the binned measurement, the reconstruction next to the
ground-truth scene, the depth map next to the true indentation, and the marker field.
"""
# The library is thintact_sdk.device.virtual_demo.run_demo and the figure
# thintact_sdk.apps.viewer.demo_figure.demo_figure; this module parses, prints and writes
# (the docstring above is the command's --help).

from __future__ import annotations

import argparse
import json

from thintact_sdk.apps.cli.argtypes import finite_float, positive_float
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output, file_input
from thintact_sdk.formats.profiles import load_profile


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="end-to-end demo on the virtual sensor (press → raw → reconstruction → depth, markers)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--profile", default="virtual-finger", help="a profile whose camera is 'virtual'")
    p.add_argument("--out", default="demo-output", help="directory for demo.png and demo.json")
    p.add_argument("--depth-mm", type=finite_float, default=0.75, help="indentation depth of the ball (mm)")
    p.add_argument("--radius-mm", type=positive_float, default=2.0, help="ball radius (mm)")
    p.add_argument("--shear-mm", type=finite_float, nargs=2, default=(0.12, -0.06), metavar=("X", "Y"),
                   help="tangential membrane shift under the ball (mm)")
    p.add_argument("--show", action="store_true", help="also open the figure in a window")
    add_force_argument(p, "into an existing non-empty --out (demo.png and demo.json are replaced)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from thintact_sdk.apps.viewer.demo_figure import demo_figure
    from thintact_sdk.device.virtual_demo import run_demo

    out = claim_output(args.out, "directory", force=args.force, inputs=(file_input(args.profile),))
    profile = load_profile(args.profile)
    demo = run_demo(profile, args.depth_mm, args.radius_mm, (args.shear_mm[0], args.shear_mm[1]))
    summary = demo.summary
    print(f"[demo] profile {profile.name}: sensor {profile.sensor.rows}×{profile.sensor.cols} px, "
          f"scene {profile.scene.rows}×{profile.scene.cols} px at {profile.scene.pixel_pitch_um} um")
    if demo.scale < 1:
        print(f"[demo] the field is small for a {args.radius_mm:g} mm ball: ball, place and shear "
              f"scaled by {demo.scale:.3f}, depth {demo.depth_mm:.2f} mm")
    out.mkdir(parents=True, exist_ok=True)
    fig_path = demo_figure(out / "demo.png", demo, profile, show=args.show)
    (out / "demo.json").write_text(json.dumps(summary, indent=1) + "\n")
    contact_rms = summary["depth_rms_error_in_contact_mm"]
    print(f"[demo] reconstruction PSNR {summary['psnr_db']:.1f} dB, SSIM {summary['ssim']:.3f}")
    print(f"[demo] depth: max {summary['depth_max_mm']['estimated']:.2f} mm "
          f"(true {summary['depth_max_mm']['true']:.2f} mm), RMS error {summary['depth_rms_error_mm']:.3f} mm "
          "over the "
          + (f"map, {contact_rms:.3f} mm where the truth is in contact; " if contact_rms is not None
             else f"map (the true press stays under the {demo.contact_threshold_mm:g} mm contact threshold); ")
          + f"contact {demo.frame.contact} over {demo.frame.contact_area_mm2:.1f} mm²")
    print(f"[demo] markers tracked {summary['markers_tracked']}, displacement RMS error "
          f"{summary['marker_displacement_rms_error_mm']:.3f} mm; raw → tactile frame "
          f"{summary['raw_to_tactile_latency_ms']:.0f} ms")
    print(f"[demo] figure: {fig_path.resolve()}")
    return 0
