"""``thintact record``: capture N frames from a profile's camera into a recording.

Parsing, the output policy and the summary lines; the recording itself is
:func:`thintact_sdk.device.capture_record.record` (a ``thintact-recording/1`` directory,
CONTRACTS §3) or :func:`~thintact_sdk.device.capture_record.record_log` (``--format mcap``).

Dropped frames (gaps in the camera's frame ids) are never silent: each gap is reported,
the count is printed at the end, and ``--fail-on-drop`` turns any drop into an error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from thintact_sdk.apps.cli.argtypes import (
    KEY_VALUE_HELP,
    key_value,
    key_values,
    positive_float,
    positive_int,
)
from thintact_sdk.apps.cli.output_path import (
    add_force_argument,
    check_not_an_input,
    claim_output,
    file_input,
)
from thintact_sdk.device.capture_loop import RecordSummary
from thintact_sdk.device.capture_record import record, record_log
from thintact_sdk.errors import DeviceError, RecordingError, ThinTactError
from thintact_sdk.formats.profiles import Profile, load_profile

CLI_DESCRIPTION = """\
Capture N frames from the profile's camera into a thintact-recording/1 directory.

Frames are binned with the profile's Bayer layout; measurements keep the black level and
are stored as uint16 when integral, else float32. Each frame records timestamp_ns,
frame_id and exposure_us (and gain_db, device_timestamp_ns, dropped_before when known);
a ground-truth scene reported by the camera (the virtual camera) is saved with it.
--raw also keeps the raw mosaics (raw/*.npy), which the replay camera delivers as recorded.

Dropped frames (gaps in the camera's frame ids) are never silent: gaps are reported as they
happen, the total at the end, and --fail-on-drop makes any drop an error (exit status 2).

--format mcap writes an MCAP log (--out FILE.mcap) with ROS 2 message encodings instead:
the raw frames and, unless --no-tactile, each frame's reconstruction, depth, markers and
contact (topics, types and how to open it: docs/logging.md).
"""

def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "record",
        help="record frames from a profile's camera into a thintact-recording/1 directory",
        description=CLI_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--profile", required=True, help="profile name or file")
    p.add_argument("--frames", type=positive_int, required=True, metavar="N",
                   help="frames to record (>= 1)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="recording directory (or .mcap file with --format mcap) to create")
    p.add_argument("--raw", action="store_true", help="also keep the raw mosaics (raw/*.npy)")
    p.add_argument("--timeout", type=positive_float, default=5.0, metavar="S",
                   help="longest wait for one frame in seconds (default 5)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", type=key_value,
                   help="override a camera setting, e.g. --set fps=0 (" + KEY_VALUE_HELP + ")")
    p.add_argument("--append", action="store_true",
                   help="add frames to an existing recording of the same device (resume)")
    p.add_argument("--fail-on-drop", action="store_true",
                   help="exit with an error if the camera dropped any frame")
    p.add_argument("--no-scenes", action="store_true",
                   help="do not save ground-truth scenes reported by the camera")
    p.add_argument("--buffer-mb", type=positive_float, default=512.0, metavar="MB",
                   help="memory for frames waiting to be written (default 512)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    mcap = p.add_argument_group("MCAP logs (--format mcap, docs/logging.md)")
    mcap.add_argument("--format", choices=("recording", "mcap"), default="recording",
                      help="thintact-recording/1 directory (default) or an MCAP file")
    mcap.add_argument("--no-tactile", action="store_true",
                      help="MCAP: raw frames only (no reconstruction, depth, markers, contact)")
    mcap.add_argument("--compression", choices=("none", "lz4", "zstd"), default="none",
                      help="MCAP chunk compression (default none: raw frames barely compress)")
    mcap.add_argument("--image-encoding", choices=("rgb8", "32FC3"), default="rgb8",
                      help="MCAP reconstruction encoding (default rgb8; 32FC3 is exact)")
    mcap.add_argument("--no-raw-preview", action="store_true",
                      help="no rgb8 /thintact/raw_preview beside 16-bit raw frames (viewers then "
                           "show the raw topic only where they decode it; saves a pass per frame)")
    add_force_argument(p, "a new recording into an existing non-empty directory that is not "
                       "a recording (an existing recording needs --append)")
    p.set_defaults(func=run)


def _record_mcap(args: argparse.Namespace, profile: Profile, out: Path) -> RecordSummary:
    """``--format mcap``: the options that only make sense for a recording directory fail."""
    for flag, given in (("--raw", args.raw), ("--append", args.append),
                        ("--no-scenes", args.no_scenes)):
        if given:
            raise ThinTactError(f"{flag} applies to --format recording only; an MCAP log "
                                "always holds the raw frames and is never appended to")
    return record_log(
        profile, args.frames, out, overwrite=args.force, tactile=not args.no_tactile,
        timeout_s=args.timeout, settings=key_values(args.set), compression=args.compression,
        image_encoding=args.image_encoding, raw_preview=False if args.no_raw_preview else None,
        progress=not args.quiet, buffer_mb=args.buffer_mb,
    )


def claim_recording_dir(path: str, append: bool, force: bool, inputs: tuple[Path | None, ...] = ()) -> Path:
    """``record``'s ``--out``: a recording there is resumed with ``--append`` and refused
    without it (``--force`` never discards recorded frames); otherwise the shared policy.
    It never overlaps one of ``inputs`` (the profile file)."""
    if str(path).strip() and (Path(path) / "manifest.json").is_file():
        check_not_an_input(path, inputs)
        if not append:
            raise RecordingError(f"{path} already holds a recording; choose a new --out or pass "
                                 "--append to add frames to it")
        return Path(path)
    return claim_output(path, "directory", force=force, inputs=inputs)


def run(args: argparse.Namespace) -> int:
    inputs = (file_input(args.profile),)
    if args.format == "mcap":
        out = claim_output(args.out, "file", force=args.force, inputs=inputs)
    else:
        out = claim_recording_dir(args.out, args.append, args.force, inputs)
    profile = load_profile(args.profile)
    if args.format == "mcap":
        summary = _record_mcap(args, profile, out)
    else:
        summary = record(
            profile, args.frames, out,
            keep_raw=args.raw, timeout_s=args.timeout, settings=key_values(args.set),
            append=args.append, scenes=not args.no_scenes, progress=not args.quiet,
            buffer_mb=args.buffer_mb,
        )
    fps = f"{summary.frames / summary.elapsed_s:.1f}" if summary.elapsed_s > 0 else "n/a"
    cam_fps = f"{summary.camera_fps:.1f}" if summary.camera_fps else "n/a"
    print(f"recorded {summary.frames} frame(s) to {out} in {summary.elapsed_s:.2f} s "
          f"({fps} fps written; camera {cam_fps} fps); dropped frames: {summary.dropped}")
    if summary.ended_early:
        print(f"warning: the source ended early: {summary.ended_early}", file=sys.stderr)
    if summary.dropped:
        where = ", ".join(f"{n} before id {fid}" for fid, n in summary.gaps[:10])
        msg = f"the camera dropped {summary.dropped} frame(s) ({where})"
        if args.fail_on_drop:
            raise DeviceError(msg + "; the recording is kept but incomplete")
        where_marked = ("the frames' sequence numbers show the gaps" if args.format == "mcap"
                        else "the manifest marks them (dropped_before)")
        print(f"warning: {msg}; {where_marked}", file=sys.stderr)
    return 0
