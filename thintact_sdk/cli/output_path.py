"""The one output-path policy of every subcommand that writes.

* ``--out ""`` is refused (it would write into the current directory).
* An output that already exists is refused unless the user passed ``--force``: a file, or a
  directory that is not empty (``--force`` writes into it, replacing files of the same
  name; it never deletes anything else).
* A file output must not name a directory, a directory output must not name a file.

Commands call :func:`claim_output` before any work, so a bad ``--out`` costs nothing.
Documented resumes (``record --append``, the calibration wizard's unfinished capture) are
decided by the command before it calls this.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Literal

from thintact_sdk.errors import OutputError

OutputKind = Literal["file", "directory"]


def add_force_argument(parser: argparse.ArgumentParser, what: str = "over an existing output") -> None:
    """Add the shared ``--force`` flag; ``what`` completes "allow writing ..." in its help."""
    parser.add_argument("--force", action="store_true",
                        help=f"allow writing {what} (files of the same name are replaced, "
                        "nothing else is deleted)")


def claim_output(
    path: str | os.PathLike[str] | None,
    kind: OutputKind,
    *,
    force: bool = False,
    option: str = "--out",
) -> Path:
    """Check an output path the user named and return it as a :class:`Path`.

    Parameters
    ----------
    path
        The path as given on the command line.
    kind
        ``"file"`` or ``"directory"``: what the command will write there.
    force
        Whether the user allowed an existing output to be overwritten.
    option
        The option's name, used in the messages.

    Raises
    ------
    OutputError
        When the path is empty, of the wrong kind, or exists (non-empty) without ``force``.
    """
    text = "" if path is None else os.fspath(path)
    if not str(text).strip():
        raise OutputError(f"{option} is empty: name the {kind} to write")
    p = Path(text).expanduser()
    if kind == "file":
        if p.is_dir():
            raise OutputError(f"{option} {p} is a directory; name the file to write")
        if p.exists() and not force:
            raise OutputError(f"{option} {p} already exists; pass --force to overwrite it "
                              "or choose another path")
        return p
    if p.exists() and not p.is_dir():
        raise OutputError(f"{option} {p} is a file; name a directory to write into")
    if p.is_dir() and not force and any(p.iterdir()):
        raise OutputError(f"{option} {p} already exists and is not empty; pass --force to write "
                          "into it (files of the same name are replaced) or choose a new directory")
    return p
