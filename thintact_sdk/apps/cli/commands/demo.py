"""``thintact demo``: a press on the built-in virtual sensor, end to end, as one figure.

A simulated 4 mm ball presses the membrane (with a little shear); the virtual camera renders
the lensless measurement through the simulator with the sensor noise model; the sensor
bins, reconstructs and interprets it exactly as it would a real camera's frames. The
figure shows the raw Bayer frame, the binned measurement, the reconstruction next to the
ground-truth scene, the depth map next to the true indentation, and the marker field.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.apps.cli.argtypes import finite_float, positive_float
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output, file_input
from thintact_sdk.device.cameras import camera_is_simulated
from thintact_sdk.device.virtual_bench import get_scene_slot
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile, load_profile


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


def _scene_slot(profile: Profile) -> Any:
    """The virtual bench's slot the profile's simulated camera renders (keyed by profile name)."""
    return get_scene_slot(profile.name)


def _stretch(img: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(img, [0.5, 99.5])
    return np.clip((img - lo) / max(hi - lo, 1e-9), 0, 1)


def run(args: argparse.Namespace) -> int:
    from thintact_sdk.device.sensor import Sensor
    from thintact_sdk.reconstruction.metrics import psnr, ssim
    from thintact_sdk.tactile import Sphere, TactileSimulator
    from thintact_sdk.tactile.calibration.ball_press import ball_radius_for_field
    from thintact_sdk.tactile.calibration.evaluation import depth_rms as depth_rms_in_contact
    from thintact_sdk.tactile.calibration.evaluation import marker_errors

    out = claim_output(args.out, "directory", force=args.force, inputs=(file_input(args.profile),))
    profile = load_profile(args.profile)
    if not camera_is_simulated(profile):
        raise ThinTactError(
            f"the demo needs a profile whose camera is the virtual sensor; {profile.name!r} uses "
            f"{profile.camera.plugin if profile.camera else 'no camera'} (try --profile virtual-finger)"
        )
    if not 0.05 <= args.depth_mm <= 2.0:
        raise ThinTactError("--depth-mm must be between 0.05 and 2.0 mm")
    out.mkdir(parents=True, exist_ok=True)

    sim = TactileSimulator.for_profile(profile)
    flat = sim.flat()
    # the press is laid out for a finger-sized field; a smaller field gets it scaled down whole
    scale = ball_radius_for_field(profile, args.radius_mm) / args.radius_mm
    depth_mm = args.depth_mm if scale == 1 else min(args.depth_mm, 0.75 * scale * args.radius_mm)
    press = sim.press(Sphere(scale * args.radius_mm), depth_mm,
                      center_mm=(scale * 1.2, scale * -0.8),
                      shear_mm=(scale * args.shear_mm[0], scale * args.shear_mm[1]))
    slot = _scene_slot(profile)
    print(f"[demo] profile {profile.name}: sensor {profile.sensor.rows}×{profile.sensor.cols} px, "
          f"scene {profile.scene.rows}×{profile.scene.cols} px at {profile.scene.pixel_pitch_um} um")
    if scale < 1:
        print(f"[demo] the field is small for a {args.radius_mm:g} mm ball: ball, place and shear "
              f"scaled by {scale:.3f}, depth {depth_mm:.2f} mm")
    with Sensor(profile, camera_settings={"fps": 0}) as sensor:
        slot.set(flat.scene)
        sensor.read()  # the first frame is the no-contact reference
        slot.set(press.scene)
        raw = sensor.read_raw()
        t0 = time.perf_counter()
        frame = sensor.process(raw)
        latency_ms = (time.perf_counter() - t0) * 1e3
        interpreter = sensor.interpreter
    slot.set(None)

    from thintact_sdk.device.cameras import to_measurement

    meas = to_measurement(raw, profile)
    truth_depth = press.depth_mm
    depth_rms = float(np.sqrt(np.mean((frame.depth_mm - truth_depth) ** 2)))
    threshold = profile.tactile.contact_threshold_mm if profile.tactile else 0.1
    contact_rms = depth_rms_in_contact(frame.depth_mm, truth_depth, threshold)
    errors, tracked = marker_errors(interpreter, frame.marker_displacements_mm, press)
    marker_rms = float(np.sqrt(np.mean(errors**2))) if tracked else float("nan")
    summary: dict[str, Any] = {
        "profile": profile.name,
        "psnr_db": psnr(np.clip(frame.image, 0, 1), press.scene),
        "ssim": ssim(np.clip(frame.image, 0, 1), press.scene),
        "depth_max_mm": {"estimated": float(frame.depth_mm.max()), "true": float(truth_depth.max())},
        "depth_rms_error_mm": depth_rms,
        "depth_rms_error_in_contact_mm": contact_rms if np.isfinite(contact_rms) else None,
        "contact": bool(frame.contact),
        "contact_area_mm2": float(frame.contact_area_mm2),
        "markers_tracked": tracked,
        "marker_displacement_rms_error_mm": marker_rms,
        "raw_to_tactile_latency_ms": latency_ms,
    }
    fig_path = _figure(out / "demo.png", raw.data, meas.signal(), frame, press, profile, summary)
    (out / "demo.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(f"[demo] reconstruction PSNR {summary['psnr_db']:.1f} dB, SSIM {summary['ssim']:.3f}")
    print(f"[demo] depth: max {summary['depth_max_mm']['estimated']:.2f} mm "
          f"(true {summary['depth_max_mm']['true']:.2f} mm), RMS error {depth_rms:.3f} mm over the "
          + (f"map, {contact_rms:.3f} mm where the truth is in contact; " if np.isfinite(contact_rms)
             else f"map (the true press stays under the {threshold:g} mm contact threshold); ")
          + f"contact {frame.contact} over {frame.contact_area_mm2:.1f} mm²")
    print(f"[demo] markers tracked {summary['markers_tracked']}, displacement RMS error "
          f"{marker_rms:.3f} mm; raw → tactile frame {latency_ms:.0f} ms")
    print(f"[demo] figure: {fig_path.resolve()}")
    if args.show:
        import matplotlib.pyplot as plt

        plt.show()
    return 0


def _figure(path: Path, raw: np.ndarray, signal: np.ndarray, frame: Any, press: Any,
            profile: Profile, summary: dict[str, Any]) -> Path:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    mm = profile.scene.pixel_pitch_um / 1000.0
    n, m = profile.scene.rows, profile.scene.cols
    extent = (-(m / 2) * mm, (m / 2) * mm, (n / 2) * mm, -(n / 2) * mm)
    fig, axes = plt.subplots(2, 4, figsize=(17, 7.5))
    ax = axes[0, 0]
    ax.imshow(raw, cmap="gray")
    ax.set_title(f"raw Bayer frame {raw.shape[0]}×{raw.shape[1]} (DN)")
    ax = axes[0, 1]
    ax.imshow(_stretch(signal))
    ax.set_title("binned measurement R, Ḡ, B (not a picture)")
    ax = axes[0, 2]
    ax.imshow(np.clip(frame.image, 0, 1), extent=extent)
    ax.set_title(f"reconstruction ({summary['psnr_db']:.1f} dB)")
    ax = axes[0, 3]
    ax.imshow(press.scene, extent=extent)
    ax.set_title("ground-truth membrane scene")
    vmax = float(max(press.depth_mm.max(), 1e-3))
    ax = axes[1, 0]
    im = ax.imshow(frame.depth_mm, cmap="viridis", vmin=0, vmax=vmax, extent=extent)
    ax.set_title(f"estimated depth (max {frame.depth_mm.max():.2f} mm)")
    fig.colorbar(im, ax=ax, fraction=0.046, label="mm")
    ax = axes[1, 1]
    im = ax.imshow(press.depth_mm, cmap="viridis", vmin=0, vmax=vmax, extent=extent)
    ax.set_title(f"true indentation (max {press.depth_mm.max():.2f} mm)")
    fig.colorbar(im, ax=ax, fraction=0.046, label="mm")
    ax = axes[1, 2]
    r = n // 2
    xs = (np.arange(m) - (m - 1) / 2) * mm
    ax.plot(xs, press.depth_mm[r], label="true")
    ax.plot(xs, frame.depth_mm[r], label="estimated")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("depth (mm)")
    ax.set_title(f"depth profile, row {r} (RMS error {summary['depth_rms_error_mm']:.3f} mm)")
    ax.legend()
    ax = axes[1, 3]
    ax.imshow(np.clip(frame.image, 0, 1), extent=extent, alpha=0.5)
    pos = frame.marker_positions_mm
    disp = frame.marker_displacements_mm
    good = np.isfinite(pos[:, 0]) & np.isfinite(disp[:, 0]) if len(pos) else np.zeros(0, bool)
    if good.any():
        ax.quiver(pos[good, 0], pos[good, 1], disp[good, 0], disp[good, 1], color="red",
                  angles="xy", scale_units="xy", scale=0.1)
    ax.set_title("marker displacements (×10)")
    ax.set_xlabel("x (mm)")
    for a in axes.flat[:4]:
        a.set_xticks([])
        a.set_yticks([])
    fig.suptitle(f"ThinTact virtual sensor '{profile.name}': {summary['depth_max_mm']['true']:.2f} mm "
                 f"ball press, contact={summary['contact']}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
