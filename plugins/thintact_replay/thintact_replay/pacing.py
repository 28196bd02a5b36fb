"""Waiting until a replayed frame is due (``rate: recorded``), shared by every replay source."""

from __future__ import annotations

import time

from thintact_sdk.errors import DeviceTimeoutError


def wait_until_due(start_s: float, offset_ns: float, speed: float, timeout_s: float,
                   what: str) -> None:
    """Sleep until the frame recorded ``offset_ns`` after the first one is due.

    Parameters
    ----------
    start_s
        ``time.monotonic()`` when the replay started, s.
    offset_ns
        The frame's recorded time after the first frame (loops included), ns.
    speed
        Playback speed (2 = twice as fast as recorded).
    timeout_s
        The caller's read timeout, s.
    what
        Names the frame in the error, e.g. ``"frame 3 of rec/"``.

    Raises
    ------
    DeviceTimeoutError
        When the frame is due later than ``timeout_s`` from now (after waiting ``timeout_s``,
        as a camera that delivers nothing would).
    """
    wait = start_s + offset_ns / 1e9 / speed - time.monotonic()
    if wait > timeout_s:
        time.sleep(max(timeout_s, 0.0))
        raise DeviceTimeoutError(f"replay: {what} is due in {wait:.2f} s, beyond the read "
                                 f"timeout of {timeout_s:.2f} s")
    if wait > 0:
        time.sleep(wait)
