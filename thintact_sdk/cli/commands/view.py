"""``thintact view PROFILE``: watch a live sensor in the browser (docs/viewer.md).

Opens the profile's sensor (virtual, replay or a real camera), serves a page on
http://127.0.0.1:PORT/ with the raw measurement, the reconstruction, the depth map, the
marker displacement arrows, contact and shear, and the frame rate and latency, and
prints the address. Runs until Ctrl-C (or --duration seconds).
"""

from __future__ import annotations

import argparse
import sys
import time

from thintact_sdk.cli.argtypes import KEY_VALUE_HELP, key_value, key_values
from thintact_sdk.errors import ThinTactError
from thintact_sdk.viewer import LiveView, ViewerServer

DEFAULT_PORT = 8765


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="watch a live sensor in the browser (served on 127.0.0.1)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("profile", metavar="PROFILE", help="profile name or file")
    p.add_argument("--port", type=int, default=DEFAULT_PORT,
                   help=f"TCP port on 127.0.0.1 (default {DEFAULT_PORT}; 0 picks a free one)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", type=key_value,
                   help="override a camera setting, e.g. --set fps=10 (" + KEY_VALUE_HELP + ")")
    p.add_argument("--reference-frames", type=int, default=1, metavar="N",
                   help="frames averaged into the no-contact reference at start (default 1)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: run until Ctrl-C)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import thintact_sdk as thintact

    if not 0 <= args.port <= 65535:
        raise ThinTactError(f"--port must be 0..65535, not {args.port}")
    if args.reference_frames < 1:
        raise ThinTactError("--reference-frames must be at least 1")
    settings = key_values(args.set)
    with ViewerServer(args.port) as server, thintact.open(
            args.profile, camera_settings=settings,
            reference_frames=args.reference_frames) as sensor:
        live = LiveView(sensor)
        server.start(live)
        print(f"viewing {sensor.profile.name} at {server.url} "
              "(keep the membrane free for the first frame; Ctrl-C stops)", flush=True)
        try:
            _serve(live, args.duration)
        finally:
            server.stop()  # the frame loop stops before the sensor closes
        stats = live.stats()
    print(f"stopped: sensor {stats['sensor_fps']} fps, served {stats['served_fps']} fps, "
          f"latency {stats['latency_ms']} ms (camera stamp -> served)")
    return 0


def _serve(live: LiveView, duration_s: float | None) -> None:
    """Wait ``duration_s`` or until Ctrl-C (the normal way to stop), saying once if the
    source fails."""
    deadline = None if duration_s is None else time.monotonic() + duration_s
    reported = False
    try:
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2)
            if live.error and not reported:
                print(f"warning: {live.error}; the page keeps the last frame", file=sys.stderr,
                      flush=True)
                reported = True
    except KeyboardInterrupt:
        pass
