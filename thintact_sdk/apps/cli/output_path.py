"""The one output-path policy of every subcommand that writes.

* ``--out ""`` is refused (it would write into the current directory).
* An output that already exists is refused unless the user passed ``--force``: a file, or a
  directory that is not empty (``--force`` writes into it, replacing files of the same
  name; it never deletes anything else).
* A file output must not name a directory, a directory output must not name a file.
* An output never overlaps one of the command's inputs, ``--force`` or not: it may not be
  an input, lie inside an input directory, or contain an input (paths compared after
  resolving symlinks and ``..``; the same file reached through a hard link counts too).
* Writers that create their output over a long time (``record``) hold an exclusive
  :func:`write_lock` on it, so of two runs racing for the same ``--out`` exactly one wins.

Commands call :func:`claim_output` before any work, so a bad ``--out`` costs nothing.
Documented resumes (``record --append``, the calibration wizard's unfinished capture) are
decided by the command before it calls this.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterable
from pathlib import Path

from thintact_sdk.errors import OutputError
from thintact_sdk.formats.output_lock import LOCK_NAME, OutputKind, write_lock

__all__ = ["LOCK_NAME", "OutputKind", "add_force_argument", "check_not_an_input", "claim_output",
           "file_input", "write_lock"]


def add_force_argument(parser: argparse.ArgumentParser, what: str = "over an existing output") -> None:
    """Add the shared ``--force`` flag; ``what`` completes "allow writing ..." in its help."""
    parser.add_argument("--force", action="store_true",
                        help=f"allow writing {what} (files of the same name are replaced, "
                        "nothing else is deleted)")


InputPath = str | os.PathLike[str] | None


def file_input(name: str | os.PathLike[str] | None) -> Path | None:
    """``name`` as an input path when it names an existing file, else None (options such as
    ``--profile`` take a built-in name or a file; only a file can be overwritten)."""
    if name is None or not str(name).strip():
        return None
    p = Path(name).expanduser()
    return p if p.is_file() else None


def _resolved(path: str | os.PathLike[str]) -> Path:
    """``path`` made absolute with every symlink and ``..`` resolved (non-existing tails kept)."""
    return Path(os.path.realpath(Path(path).expanduser()))


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_not_an_input(
    path: str | os.PathLike[str],
    inputs: Iterable[InputPath],
    *,
    option: str = "--out",
) -> None:
    """Refuse an output that equals, lies inside or contains one of ``inputs``.

    ``inputs`` are the command's input files and directories (None entries are skipped, and
    so are paths that do not exist: nothing there can be destroyed, and the command names the
    missing input itself).
    Paths are compared after resolving symlinks and ``..`` (:func:`os.path.realpath`), and
    an existing output that is the same file as an input (a hard link) is refused too.

    Raises
    ------
    OutputError
        Naming the option, the output and the input it would overwrite.
    """
    out = _resolved(path)
    for given in inputs:
        if given is None or not str(given).strip() or not os.path.exists(Path(given).expanduser()):
            continue
        src = _resolved(given)
        if out == src or _same_file(out, src):
            why = "is"
        elif out.is_relative_to(src):
            why = "lies inside"
        elif src.is_relative_to(out):
            why = "contains"
        else:
            continue
        raise OutputError(f"{option} {path} {why} the input {given}; writing there would destroy "
                          "the input (--force does not allow it): choose another output path")


def claim_output(
    path: str | os.PathLike[str] | None,
    kind: OutputKind,
    *,
    force: bool = False,
    option: str = "--out",
    inputs: Iterable[InputPath] = (),
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
    inputs
        The command's input files and directories: the output may not overlap any of them
        (:func:`check_not_an_input`), whatever ``force`` says.

    Raises
    ------
    OutputError
        When the path is empty, of the wrong kind, a device, pipe or socket, overlaps an
        input, or exists (non-empty; a dangling symbolic link counts) without ``force``.
    """
    text = "" if path is None else os.fspath(path)
    if not str(text).strip():
        raise OutputError(f"{option} is empty: name the {kind} to write")
    p = Path(text).expanduser()
    check_not_an_input(p, inputs, option=option)
    if p.is_symlink() and not p.exists() and not force:  # a dangling link: it would write elsewhere
        raise OutputError(f"{option} {p} is a symbolic link to {os.readlink(p)!r}, which does not exist; "
                          "pass --force to write through it or choose another path")
    if p.exists() and not (p.is_file() or p.is_dir()):  # a device, FIFO or socket
        raise OutputError(f"{option} {p} is not a regular file or directory (a device, pipe or "
                          "socket); name a file to write")
    if kind == "file":
        if p.is_dir():
            raise OutputError(f"{option} {p} is a directory; name the file to write")
        if p.exists() and not force:
            raise OutputError(f"{option} {p} already exists; pass --force to overwrite it "
                              "or choose another path")
        return p
    if p.exists() and not p.is_dir():
        raise OutputError(f"{option} {p} is a file; name a directory to write into")
    if p.is_dir() and not force and any(q.name != LOCK_NAME for q in p.iterdir()):
        raise OutputError(f"{option} {p} already exists and is not empty; pass --force to write "
                          "into it (files of the same name are replaced) or choose a new directory")
    return p
