"""Stopping long-running commands on Ctrl-C and SIGTERM, also when they were started with SIGINT
ignored (a background job of a shell script), as ``thintact view`` and ``thintact live`` do."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType


class Stop:
    """What SIGINT and SIGTERM do to a long-running command (the viewer, the live server).

    While the sensor opens (``serving`` false) a signal raises KeyboardInterrupt, which cuts
    the open short; once the command serves, the first signal sets ``event`` (its main loop
    then stops what it serves and the sensor, in that order) and a second one
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
def stop_signals() -> Iterator[Stop]:
    """Route SIGINT and SIGTERM to a :class:`Stop` while the command runs (main thread only;
    the previous handlers come back afterwards). SIGINT is taken even where the parent
    started the command with it ignored (a background job of a script)."""
    stop = Stop()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
