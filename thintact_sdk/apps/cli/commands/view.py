"""``thintact view PROFILE [PROFILE ...]``: watch live sensors in the browser (docs/viewer.md).

Opens each profile's sensor (virtual, replay or a real camera), serves a page on
http://127.0.0.1:PORT/ with, per sensor, the raw measurement, the reconstruction, the
depth map, the marker displacement arrows, contact and shear, and the frame rate and
latency, and prints the address. Each sensor's snapshot and record buttons write under
--out (default ./thintact-view). Runs until Ctrl-C, SIGTERM or --duration seconds; a stop by the user
exits 0 after stopping the server and closing the sensor.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import threading
import time
from typing import TYPE_CHECKING

from thintact_sdk.apps.cli.argtypes import (
    KEY_VALUE_HELP,
    key_value,
    key_values,
    non_negative_float,
    port,
    positive_int,
)
from thintact_sdk.apps.cli.stop_signals import stop_signals
from thintact_sdk.apps.viewer import LiveView, ViewerServer
from thintact_sdk.apps.viewer.snapshots import DEFAULT_OUT
from thintact_sdk.errors import ThinTactError

if TYPE_CHECKING:
    from thintact_sdk.device.sensor import Sensor

DEFAULT_PORT = 8765


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="watch live sensors in the browser (served on 127.0.0.1)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("profiles", nargs="+", metavar="PROFILE",
                   help="profile name or file; several show one panel group each")
    p.add_argument("--port", type=port, default=DEFAULT_PORT,
                   help=f"TCP port on 127.0.0.1 (default {DEFAULT_PORT}; 0 picks a free one)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", type=key_value,
                   help="override a camera setting, e.g. --set fps=10 (" + KEY_VALUE_HELP + ")")
    p.add_argument("--reference-frames", type=positive_int, default=1, metavar="N",
                   help="frames averaged into the no-contact reference at start (default 1)")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"where the page's snapshot and record buttons write (default ./{DEFAULT_OUT}; "
                        "created on first use)")
    p.add_argument("--duration", type=non_negative_float, default=None, metavar="S",
                   help="stop after S seconds (default: run until Ctrl-C)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import thintact_sdk as thintact

    settings = key_values(args.set)
    if not args.out.strip():
        raise ThinTactError("--out must name a directory")
    with stop_signals() as stop:
        try:
            with ViewerServer(args.port) as server, contextlib.ExitStack() as sensors:
                opened = [sensors.enter_context(thintact.open(
                    profile, camera_settings=settings, reference_frames=args.reference_frames))
                    for profile in args.profiles]
                lives = [LiveView(sensor, title=title, out=args.out, label=label)
                         for sensor, (title, label) in zip(opened, _names(opened), strict=True)]
                server.start(lives)  # stops them before the sensors close
                names = ", ".join(sensor.profile.name for sensor in opened)
                stop.serving = True  # before the URL: a signal after it must end the serving
                print(f"viewing {names} at {server.url} "
                      "(keep the membranes free for the first frame; Ctrl-C stops)", flush=True)
                try:
                    _serve(lives, args.duration, stop.event)
                finally:
                    server.stop()
                stats = [live.stats() for live in lives]
        except KeyboardInterrupt:
            if not stop.event.is_set():
                raise
            print("stopped before the viewer started", file=sys.stderr)
            return 0
    for live, st in zip(lives, stats, strict=True):
        rec = st["recording"]
        saved = f"; recorded {rec['frames']} frames in {rec['path']}" if rec else ""
        print(f"stopped{'' if len(lives) == 1 else ' ' + live.label}: sensor {st['sensor_fps']} fps, "
              f"served {st['served_fps']} fps, latency {st['latency_ms']} ms "
              f"(camera stamp -> served){saved}")
    return 0


def _names(sensors: list[Sensor]) -> list[tuple[str, str]]:
    """``(title, label)`` per sensor; a profile opened twice is told apart by its position."""
    counts: dict[str, int] = {}
    for sensor in sensors:
        counts[sensor.profile.name] = counts.get(sensor.profile.name, 0) + 1
    out = []
    for k, sensor in enumerate(sensors):
        name = sensor.profile.name
        label = name if counts[name] == 1 else f"{name}-{k}"
        out.append((f"thintact view {label}", label))
    return out


def _serve(lives: list[LiveView], duration_s: float | None, stop: threading.Event) -> None:
    """Wait ``duration_s`` or until ``stop`` is set (Ctrl-C, SIGTERM), saying once per
    sensor if its source fails."""
    deadline = None if duration_s is None else time.monotonic() + duration_s
    reported: set[int] = set()
    while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
        left = 0.2 if deadline is None else max(0.0, min(0.2, deadline - time.monotonic()))
        stop.wait(left)
        for k, live in enumerate(lives):
            if live.error and k not in reported:
                print(f"warning: {live.label}: {live.error}; the page keeps the last frame",
                      file=sys.stderr, flush=True)
                reported.add(k)
