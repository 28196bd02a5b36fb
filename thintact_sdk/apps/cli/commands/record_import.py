"""``thintact record import FOLDER --profile P --out REC``: camera files → a recording.

The library side is :mod:`thintact_sdk.formats.recording_import` (roles, colour order, tone curve,
crop, mono conversion, binning).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from thintact_sdk.apps.cli.argtypes import positive_int
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output, file_input


def _crop(text: str) -> tuple[int, int, int, int]:
    parts = text.split(",")
    try:
        x, y, w, h = (int(v) for v in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected X,Y,W,H (four integers, pixels)") from None
    if x < 0 or y < 0 or w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: X, Y >= 0 and W, H >= 1 pixels")
    return x, y, w, h


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "record-import",
        help="make a thintact-recording/1 from a folder of images or videos (flat, dark, no-press, presses)",
        description="Each file (PNG/TIFF 8/16 bit, JPEG, .npy, or an MJPEG/MP4/AVI video averaged into "
        "one frame) is a frame whose role its name gives (flat/white, dark, reference/no-press, "
        "press_*) or --map/--role assign (white, dark, reference, press, scene=PATH for a frame "
        "showing a known scene). Colour order, crop, the tone curve undone, mono conversion (an RGB "
        "frame of a mono profile, reported) and binning to the profile's sensor are applied; "
        "measurements are written as float32 linear DN. A file that does not fit the profile is "
        "refused naming it and the expected shape. Also spelled 'thintact record import'.",
    )
    p.add_argument("folder", type=Path, metavar="FOLDER", help="folder of camera files")
    p.add_argument("--profile", required=True, help="profile name or file")
    p.add_argument("--out", required=True, type=Path, metavar="REC", help="recording directory to create")
    p.add_argument("--map", type=Path, metavar="MAP.yaml", help="YAML mapping of file name: role")
    p.add_argument("--role", action="append", default=[], metavar="FILE=ROLE",
                   help="role of one file (white, dark, reference, press, scene=PATH); repeatable, "
                   "overrides --map and the file name")
    p.add_argument("--colour-order", "--color-order", choices=("RGB", "BGR"), default="RGB",
                   help="channel order the camera wrote (default RGB: as the file decodes)")
    p.add_argument("--linearize", default="profile", metavar="HOW",
                   help="tone curve to undo: profile (its sensor.tone_curve, default), none (files are "
                   "linear), srgb, or gamma=G (linear = delivered^G, e.g. gamma=2.2)")
    p.add_argument("--crop", type=_crop, metavar="X,Y,W,H", help="crop in file pixels before binning")
    p.add_argument("--max-video-frames", type=positive_int, metavar="N",
                   help="average at most N frames of each video (default: all)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    add_force_argument(p, "into an existing non-empty --out")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    from thintact_sdk.errors import RecordingError
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.formats.recording_import import (
        ImportOptions,
        import_folder,
        parse_mapping_args,
        read_mapping,
    )

    if not args.folder.is_dir():
        raise RecordingError(f"{args.folder}: not a folder of camera files")
    claim_output(args.out, "directory", force=args.force,
                 inputs=(args.folder, args.map, file_input(args.profile)))
    profile = load_profile(args.profile)
    mapping = parse_mapping_args(args.role, read_mapping(args.map) if args.map else None)
    opts = ImportOptions(colour_order=args.colour_order, linearize=args.linearize, crop=args.crop,
                         max_video_frames=args.max_video_frames, mapping=mapping)
    frames = import_folder(args.folder, profile, args.out, opts,
                           None if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True)))
    for f in frames:
        notes = f"  ({'; '.join(f.notes)})" if f.notes else ""
        print(f"{f.label:16s} {f.role:9s} <- {f.source}{notes}")
    print(f"recording: {args.out} ({len(frames)} frames, profile {profile.name!r})")
    return 0
