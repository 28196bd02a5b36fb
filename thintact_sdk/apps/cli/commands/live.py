"""``thintact live PROFILE``: stream a sensor to Foxglove / Lichtblick over WebSocket.

Opens the profile's sensor and publishes every camera frame and its tactile frame on the
topics and ROS 2 schemas of an MCAP log (``/thintact/raw``, ``/thintact/image``,
``/thintact/depth``, ``/thintact/markers``, ``/thintact/contact``, ``/thintact/force``,
``/thintact/slip``; docs/logging.md), stamped in wall time, on ws://127.0.0.1:PORT
(Foxglove: Open connection → Foxglove WebSocket). Runs until Ctrl-C, --duration or
--frames; needs ``pip install 'thintact-sdk[live]'``.
"""

from __future__ import annotations

import argparse
import time

from thintact_sdk.apps.cli.argtypes import (
    KEY_VALUE_HELP,
    key_value,
    key_values,
    non_negative_float,
    port,
    positive_int,
)
from thintact_sdk.apps.cli.stop_signals import stop_signals
from thintact_sdk.apps.foxglove_live import DEFAULT_HOST, DEFAULT_PORT, LiveServer


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "live",
        help="stream a sensor to Foxglove/Lichtblick (WebSocket on 127.0.0.1)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("profile", metavar="PROFILE", help="profile name or file")
    p.add_argument("--port", type=port, default=DEFAULT_PORT,
                   help=f"TCP port (default {DEFAULT_PORT}; 0 picks a free one)")
    p.add_argument("--host", default=DEFAULT_HOST,
                   help=f"address to bind (default {DEFAULT_HOST}: this machine only; "
                        "0.0.0.0 serves the network without authentication)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", type=key_value,
                   help="override a camera setting, e.g. --set fps=10 (" + KEY_VALUE_HELP + ")")
    p.add_argument("--image-encoding", choices=("rgb8", "32FC3"), default="rgb8",
                   help="/thintact/image encoding (default rgb8)")
    p.add_argument("--duration", type=non_negative_float, default=None, metavar="S",
                   help="stop after S seconds (default: run until Ctrl-C)")
    p.add_argument("--frames", type=positive_int, default=None, metavar="N",
                   help="stop after N frames")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import thintact_sdk as thintact

    settings = key_values(args.set)
    sent = 0
    with stop_signals() as stop:
        try:
            with thintact.open(args.profile, camera_settings=settings) as sensor, LiveServer(
                    sensor.profile, host=args.host, port=args.port,
                    image_encoding=args.image_encoding) as server:
                stop.serving = True  # before the URL: a signal after it must end the serving
                print(f"streaming {sensor.profile.name} on {server.url} "
                      "(Foxglove: Open connection -> Foxglove WebSocket; Ctrl-C stops)", flush=True)
                deadline = None if args.duration is None else time.monotonic() + args.duration
                while not stop.event.is_set() and (args.frames is None or sent < args.frames) and (
                        deadline is None or time.monotonic() < deadline):
                    raw = sensor.read_raw()
                    server.publish(raw, sensor.process(raw))
                    sent += 1
        except KeyboardInterrupt:
            if not stop.event.is_set():
                raise
    print(f"stopped after {sent} frame(s)")
    return 0
