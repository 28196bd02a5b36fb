"""Entry point of the ``thintact`` command.

Subcommands come from every module of :mod:`thintact_sdk.apps.cli.commands` (each defines
``register(subparsers)`` and sets ``func`` on its parser) and from plugins' CLI
components. Errors a user can act on print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence
from typing import NoReturn

from pydantic import ValidationError

from thintact_sdk import __version__
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import validation_error_line

EXIT_USAGE = 2


def _one_line(message: str) -> str:
    """``message`` on one line: a multi-line error (a headline, then one problem a line)
    becomes ``headline: first problem (and N more)``; pydantic errors are made one line
    where they are raised (:func:`thintact_sdk.formats.profiles.validation_error_line`)."""
    lines = [ln.strip() for ln in message.splitlines() if ln.strip()]
    if len(lines) <= 1:
        return lines[0] if lines else message
    return f"{lines[0].rstrip(':')}: {lines[1].lstrip('- ')}" + (
        f" (and {len(lines) - 2} more)" if len(lines) > 2 else "")


class _Parser(argparse.ArgumentParser):
    """argparse parser whose errors are one line and exit status 2 (argparse's default);
    ``command_names`` lists the subcommands :func:`build_parser` registered."""

    command_names: list[str] = []

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The full parser with every built-in and plugin subcommand."""
    parser = _Parser(
        prog="thintact",
        description="ThinTact SDK: lensless vision-based tactile sensors.",
    )
    parser.add_argument("--version", action="version", version=f"thintact-sdk {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    import thintact_sdk.apps.cli.commands as pkg

    for mod_info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
        if mod_info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{pkg.__name__}.{mod_info.name}")
        register = getattr(mod, "register", None)
        if register is not None:
            register(sub)
    try:
        from thintact_sdk.device.registry import get_registry

        registry = get_registry()
        for name in registry.components("cli_command"):
            try:
                registry.create("cli_command", name, sub)
            except ThinTactError:  # recorded on its plugin (`thintact plugins` shows it)
                continue
    except ThinTactError:
        pass
    parser.command_names = list(sub.choices or ())
    return parser


def join_two_word_command(argv: Sequence[str], commands: Sequence[str]) -> list[str]:
    """``calibrate pose ...`` → ``calibrate-pose ...`` where ``calibrate-pose`` is a command.

    The hyphenated names are the commands; the two-word spelling (as the docs and the issue
    tracker write them) is the same command, so neither spelling is an error.

    Parameters
    ----------
    argv
        The arguments after the program name.
    commands
        Every registered subcommand name.

    Returns
    -------
    list of str
        ``argv`` with its first two words joined where that names a command, else unchanged.
    """
    args = list(argv)
    if len(args) >= 2 and not args[1].startswith("-") and f"{args[0]}-{args[1]}" in commands:
        return [f"{args[0]}-{args[1]}", *args[2:]]
    return args


def _printable_paths() -> None:
    """Let stdout and stderr print any path the file system holds: a name that is not valid
    UTF-8 reaches Python as surrogates, and printing it ended a finished command in
    ``UnicodeEncodeError`` (exit 1). Such characters are written as ``\\udcff`` escapes."""
    for stream in (sys.stdout, sys.stderr):
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            with contextlib.suppress(ValueError, OSError):  # a stream that cannot change now
                reconfigure(errors="backslashreplace")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit status (0 ok, 2 bad input or device fault)."""
    _printable_paths()
    parser = build_parser()
    argv = join_two_word_command(sys.argv[1:] if argv is None else argv,
                                 getattr(parser, "command_names", []))
    try:
        args = parser.parse_args(argv)
    except SystemExit as done:  # --help and --version exit 0 as argparse does
        if done.code in (0, None):
            raise
        return EXIT_USAGE
    if not getattr(args, "func", None):
        print(f"{parser.prog}: no command given; try '{parser.prog} --help'", file=sys.stderr)
        return EXIT_USAGE
    try:
        rc = args.func(args)
    except ThinTactError as err:
        print(f"thintact: error: {_one_line(str(err))}", file=sys.stderr)
        return EXIT_USAGE
    except ValidationError as err:  # a model built from user input: the first error, one line
        print(f"thintact: error: {validation_error_line(err)}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as err:  # a file or device the user named cannot be used
        print(f"thintact: error: {err.strerror or err}: {err.filename or ''}".rstrip(": "), file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("thintact: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # noqa: BLE001 - a bug: say so in one line, traceback on request
        if os.environ.get("THINTACT_DEBUG"):
            raise
        print(f"thintact: internal error: {type(err).__name__}: {_one_line(str(err))} "
              "(set THINTACT_DEBUG=1 for the traceback and please report it)", file=sys.stderr)
        return 1
    return int(rc or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
