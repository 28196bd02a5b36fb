"""``thintact calibrate-direct --profile P --recording REC --out CAL``: a bundle from the
profile's design by direct generation (no slit frames).

The profile should already hold the mask's pose (``thintact calibrate pose``). The system
matrices come from :meth:`thintact_sdk.reconstruction.t2s.SystemMatrices.direct`, in DN with the
scale the recording's white (flat) frame fixes; the rest (joint filter training, τ and the
decoder chosen on the recording's validation frames, the bundle) is the path of
``calibrate-import`` (:func:`thintact_sdk.apps.cli.commands.calibrate_matrices.write_bundle`).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

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


def validation_scene_count(rec: Any) -> tuple[int, int]:
    """``(frames, distinct scenes)`` among ``rec``'s validation frames: frames with a scene that
    is neither dark nor a slit, as :func:`thintact_sdk.calibration.pipeline.bundle_from_matrices`
    takes them."""
    import hashlib

    import numpy as np

    from thintact_sdk.calibration.classify import classify_scene, is_dark, is_slit

    keys = []
    for i in range(len(rec)):
        scene = rec.scene(i)
        if scene is not None and not is_dark(r := classify_scene(scene)) and not is_slit(r):
            keys.append(hashlib.sha256(np.ascontiguousarray(scene, np.float32).tobytes()).hexdigest())
    return len(keys), len(set(keys))


def white_scale_dn(unit: Any, rec: Any) -> tuple[float, str]:
    """DN above black of a white scene through an open mask, from ``rec``'s white frame: the
    ratio of its mean (minus the dark level) to the mean of ``unit`` (the direct matrices at
    unit scale) on a white scene."""
    import numpy as np

    from thintact_sdk.calibration.collect import white_frame_signal
    from thintact_sdk.errors import CalibrationError

    white = white_frame_signal(rec)
    if white is None:
        raise CalibrationError(f"recording {rec.root} has no white (flat) frame to scale the matrices; "
                               "give --scale-dn")
    raw, _, source = white
    signal = float(np.mean(raw))
    model = float(np.mean(unit.forward(np.ones((*unit.scene_shape, unit.channels)))))
    if not (signal > 0 and model > 0):
        raise CalibrationError(f"{rec.root}: white {source} has mean {signal:.4g} DN; "
                               "no scale can be taken from it")
    return signal / model, f"white {source}"


def run(args: argparse.Namespace) -> int:
    import sys

    import numpy as np

    from thintact_sdk.apps.cli.commands.calibrate_matrices import write_bundle
    from thintact_sdk.calibration.tau import MIN_SCENES_PER_FOLD
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.reconstruction.t2s import SystemMatrices

    claim_output(args.out, "directory", force=args.force, inputs=(args.recording, file_input(args.profile)))
    profile = load_profile(args.profile)
    rec = Recording(args.recording)
    print("[1/2] direct generation of the system matrices", file=sys.stderr, flush=True)
    unit = SystemMatrices.direct(profile, scale_dn=1.0)
    if args.scale_dn is not None:
        scale, source = float(args.scale_dn), "--scale-dn"
    else:
        scale, source = white_scale_dn(unit, rec)
    root = float(np.sqrt(scale))  # each matrix by sqrt(scale): the model by scale, as direct() does
    sm = SystemMatrices(unit.Po * root, unit.Qo * root, unit.Pc * root, unit.Qc * root,
                        {**unit.meta, "scale_dn": scale})
    sm.meta["imported_from"] = f"direct generation from profile {profile.name!r}"
    print(f"direct generation: {profile.mask.K} cells, scale {scale:.4g} DN ({source})")
    angle = float(sm.meta.get("unmodelled_angle_deg") or 0.0)
    if angle:
        print(f"note: the mask's residual turn of {angle:.3g} deg is held only as its separable mean")
    frames, distinct = validation_scene_count(rec)
    needed = 2 * MIN_SCENES_PER_FOLD
    print("[2/2] filter training, tau and decoder choice, bundle", file=sys.stderr, flush=True)
    bundle = write_bundle(profile, sm, args, rec)
    criterion = bundle.meta.get("metrics", {}).get("tau_selection", {}).get("criterion")
    if args.tau is None and criterion != "cross-validation":
        print(f"warning: {args.recording} has {distinct} distinct validation scene(s) ({frames} frame(s) "
              f"with a known scene that is neither dark nor a slit); choosing tau and the decoder on the "
              f"unit needs {needed} ({MIN_SCENES_PER_FOLD} per fold), so they were chosen by "
              f"'{criterion}' instead of on its own frames; record more scenes (a scene=PATH role in "
              "'thintact record import') to choose them on the unit", file=sys.stderr)
    return 0
