"""Progress lines for long tactile commands, whether or not the output is a terminal.

On a terminal a transient status line is updated in place; otherwise (output to a file or a
pipe, a CI log) each stage is one line ``[12.3 s] message`` on stderr, flushed at once, so a
long run is never silent.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO


@contextmanager
def stage_reporter(quiet: bool = False, stream: TextIO | None = None) -> Iterator[Callable[[str], None]]:
    """Yield ``say(message)``: a status line on a terminal, timestamped lines elsewhere,
    nothing when ``quiet``."""
    out = sys.stderr if stream is None else stream
    if quiet:
        yield lambda _msg: None
        return
    t0 = time.perf_counter()
    if out.isatty():
        from rich.console import Console

        con = Console(file=out)
        with con.status("working...") as status:
            yield lambda msg: status.update(f"[{time.perf_counter() - t0:.1f} s] {msg}")
        return

    def say(msg: str) -> None:
        out.write(f"[{time.perf_counter() - t0:.1f} s] {msg}\n")
        out.flush()

    yield say
