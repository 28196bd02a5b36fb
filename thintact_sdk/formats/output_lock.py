"""An exclusive claim on an output path while it is written (``record``'s recording
directory or MCAP file): of several processes racing for the same output exactly one
writes, the others get an :class:`~thintact_sdk.errors.OutputError` naming the lock."""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Literal

from thintact_sdk.errors import OutputError

OutputKind = Literal["file", "directory"]
"""What is written at the path: one file, or a directory of files."""


LOCK_NAME = ".thintact-write.lock"
"""The lock file :func:`write_lock` keeps inside a directory output while it is written."""


@contextlib.contextmanager
def write_lock(path: str | os.PathLike[str], kind: OutputKind, *, option: str = "--out") -> Iterator[Path]:
    """Hold an exclusive claim on the output ``path`` while it is written.

    A directory output is created if needed and locked through ``path/.thintact-write.lock``;
    a file output through the hidden sibling ``.<name>.lock``. The lock is an advisory
    :func:`fcntl.flock` (released by the kernel if the process dies, so a killed writer
    leaves no stale claim; where there is no ``flock`` an ``O_CREAT | O_EXCL`` file is the
    claim). The lock file is removed when the block ends, and a directory the lock created is
    removed again if nothing was written into it. Decide whether the output may be
    written (it already holds a recording, ...) inside the block: only then is the answer
    free of races.

    Raises
    ------
    OutputError
        When another process (or thread) holds the claim.
    """
    p = Path(path).expanduser()
    created = kind == "directory" and not p.exists()
    if kind == "directory":
        try:
            p.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise OutputError(f"{option} {p}: cannot create the directory ({err.strerror or err})") from None
        lock = p / LOCK_NAME
    else:
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise OutputError(f"{option} {p}: cannot create its directory ({err.strerror or err})") from None
        lock = p.with_name(f".{p.name}.lock")
    busy = OutputError(f"{option} {p} is being written by another process (lock {lock}); wait for "
                       "it to finish or choose another path")
    fd = _acquire(lock, busy, option)
    try:
        yield p
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()
        os.close(fd)  # closing the descriptor releases the flock
        if created:  # a writer that failed before writing anything leaves nothing behind
            with contextlib.suppress(OSError):
                p.rmdir()  # only if empty


def _acquire(lock: Path, busy: OutputError, option: str) -> int:
    """Open and exclusively lock ``lock``; the descriptor is returned, the lock held."""
    try:
        import fcntl
    except ImportError:  # no flock: the exclusive creation of the file is the claim
        try:
            return os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            raise busy from None
        except OSError as err:
            raise OutputError(f"{option}: cannot create the lock {lock} ({err.strerror or err})") from None
    while True:
        try:
            fd = os.open(lock, os.O_CREAT | os.O_RDWR, 0o644)
        except OSError as err:
            raise OutputError(f"{option}: cannot create the lock {lock} ({err.strerror or err})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            os.close(fd)
            if err.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EACCES):
                raise busy from None
            raise OutputError(f"{option}: cannot lock {lock} ({err.strerror or err})") from None
        try:  # the holder before us may have removed the file we opened: lock the one in place
            if os.fstat(fd).st_ino == os.stat(lock).st_ino:
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)
