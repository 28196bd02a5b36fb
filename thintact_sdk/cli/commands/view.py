"""``thintact view PROFILE``: watch a live sensor in the browser (docs/viewer.md).

Opens the profile's sensor (virtual, replay or a real camera), serves a page on
http://127.0.0.1:PORT/ with the raw measurement, the reconstruction, the depth map, the
marker displacement arrows, contact and shear, and the frame rate and latency, and
prints the address. Runs until Ctrl-C, SIGTERM or --duration seconds; a stop by the user
exits 0 after stopping the server and closing the sensor.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

from thintact_sdk.cli.argtypes import (
    KEY_VALUE_HELP,
    key_value,
    key_values,
    non_negative_float,
    positive_int,
)
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
    p.add_argument("--reference-frames", type=positive_int, default=1, metavar="N",
                   help="frames averaged into the no-contact reference at start (default 1)")
    p.add_argument("--duration", type=non_negative_float, default=None, metavar="S",
                   help="stop after S seconds (default: run until Ctrl-C)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import thintact_sdk as thintact

    if not 0 <= args.port <= 65535:
        raise ThinTactError(f"--port must be 0..65535, not {args.port}")
    settings = key_values(args.set)
    with _stop_signals() as stop:
        try:
            with ViewerServer(args.port) as server, thintact.open(
                    args.profile, camera_settings=settings,
                    reference_frames=args.reference_frames) as sensor:
                live = LiveView(sensor)
                server.start(live)
                print(f"viewing {sensor.profile.name} at {server.url} "
                      "(keep the membrane free for the first frame; Ctrl-C stops)", flush=True)
                stop.serving = True
                try:
                    _serve(live, args.duration, stop.event)
                finally:
                    server.stop()  # the frame loop stops before the sensor closes
                stats = live.stats()
        except KeyboardInterrupt:
            if not stop.event.is_set():
                raise
            print("stopped before the viewer started", file=sys.stderr)
            return 0
    print(f"stopped: sensor {stats['sensor_fps']} fps, served {stats['served_fps']} fps, "
          f"latency {stats['latency_ms']} ms (camera stamp -> served)")
    return 0


class _Stop:
    """What SIGINT and SIGTERM do to a running viewer.

    While the sensor opens (``serving`` false) a signal raises KeyboardInterrupt, which cuts
    the open short; once the viewer serves, the first signal sets ``event`` (the main loop
    then stops the server, the frame loop and the sensor in that order) and a second one
    raises KeyboardInterrupt for a user who will not wait.
    """

    def __init__(self) -> None:
        self.event = threading.Event()
        self.serving = False

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        first = not self.event.is_set()
        self.event.set()
        if not self.serving or not first:
            raise KeyboardInterrupt


@contextmanager
def _stop_signals() -> Iterator[_Stop]:
    """Route SIGINT and SIGTERM to a :class:`_Stop` while the viewer runs (main thread only;
    the previous handlers come back afterwards). SIGINT is taken even where the parent
    started the command with it ignored (a background job of a script)."""
    stop = _Stop()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _serve(live: LiveView, duration_s: float | None, stop: threading.Event) -> None:
    """Wait ``duration_s`` or until ``stop`` is set (Ctrl-C, SIGTERM), saying once if the
    source fails."""
    deadline = None if duration_s is None else time.monotonic() + duration_s
    reported = False
    while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
        left = 0.2 if deadline is None else max(0.0, min(0.2, deadline - time.monotonic()))
        stop.wait(left)
        if live.error and not reported:
            print(f"warning: {live.error}; the page keeps the last frame", file=sys.stderr,
                  flush=True)
            reported = True
