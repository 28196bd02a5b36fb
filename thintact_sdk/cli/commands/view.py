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
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import TYPE_CHECKING

from thintact_sdk.cli.argtypes import (
    KEY_VALUE_HELP,
    key_value,
    key_values,
    non_negative_float,
    port,
    positive_int,
)
from thintact_sdk.errors import ThinTactError
from thintact_sdk.viewer import LiveView, ViewerServer
from thintact_sdk.viewer.capture import DEFAULT_OUT

if TYPE_CHECKING:
    from thintact_sdk.sensor import Sensor

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

    if not 0 <= args.port <= 65535:
        raise ThinTactError(f"--port must be 0..65535, not {args.port}")
    settings = key_values(args.set)
    if not args.out.strip():
        raise ThinTactError("--out must name a directory")
    with _stop_signals() as stop:
        try:
            with ViewerServer(args.port) as server, contextlib.ExitStack() as sensors:
                opened = [sensors.enter_context(thintact.open(
                    profile, camera_settings=settings, reference_frames=args.reference_frames))
                    for profile in args.profiles]
                lives = [LiveView(sensor, title=title, out=args.out, label=label)
                         for sensor, (title, label) in zip(opened, _names(opened), strict=True)]
                server.start(lives)  # stops them before the sensors close
                names = ", ".join(sensor.profile.name for sensor in opened)
                print(f"viewing {names} at {server.url} "
                      "(keep the membranes free for the first frame; Ctrl-C stops)", flush=True)
                stop.serving = True
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
