"""Running one fuzzed CLI invocation and judging it against the one rule.

The rule (issue 18): exit 0 with a finite, correct result, or exit 2 with one clear error
line; never a traceback, "internal error" or another exit status; nothing written outside
the output the user named. :func:`judge` classifies an invocation as ``"clean error"`` or
``"correct result"`` and fails the test on anything else, counting outcomes in
:data:`rob_kit.FUZZ_OUTCOMES`.
"""

from __future__ import annotations

import contextlib
import os
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import rob_kit

from thintact_sdk.apps.cli.main import main

NOISE = ("Traceback", "internal error", "DLASCL", "RuntimeWarning", "LinAlgError", "Warning:")


@contextlib.contextmanager
def working_dir(path: Path) -> Iterator[None]:
    old = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    """``{relative path: (size, mtime_ns)}`` of every file under ``root``."""
    out = {}
    for p in root.rglob("*"):
        if p.is_file() and not p.is_symlink():
            st = p.stat()
            out[str(p.relative_to(root))] = (st.st_size, st.st_mtime_ns)
    return out


def run_cli(argv: list[str], cwd: Path, capfd: Any) -> tuple[int, str]:
    """``main(argv)`` run in ``cwd``; returns the exit status and stderr (Python and C level)."""
    capfd.readouterr()
    with working_dir(cwd):
        try:
            rc = main(argv)
        except SystemExit as done:  # --help / --version
            rc = done.code if isinstance(done.code, int) else 0
    return int(rc), capfd.readouterr().err


def judge(target: str, argv: list[str], rc: int, err: str, check_result: Callable[[], None],
          result_codes: tuple[int, ...] = (0,)) -> str:
    """Classify one invocation; raise AssertionError for anything outside the rule."""
    counts = rob_kit.FUZZ_OUTCOMES.setdefault(target, Counter())
    lines = [ln for ln in err.splitlines() if ln.strip()]
    noisy = [ln for ln in lines if any(n in ln for n in NOISE)]
    errors = [ln for ln in lines if "error:" in ln]
    if rc == 2 and len(errors) == 1 and lines[-1] == errors[0] and not noisy:
        outcome = "clean error"
    elif rc in result_codes and not errors and not noisy:
        try:
            check_result()
        except Exception as exc:  # noqa: BLE001 - reported with the input
            counts["anything else"] += 1
            raise AssertionError(f"{target}: exit {rc} but the result is wrong for {argv}: {exc}") from exc
        outcome = "correct result"
    else:
        counts["anything else"] += 1
        raise AssertionError(f"{target}: exit {rc} for {argv}; stderr:\n{err}")
    counts[outcome] += 1
    return outcome


def assert_nothing_outside(work: Path, inputs: Path, before: dict[str, tuple[int, int]],
                           out_token: str | None) -> None:
    """Inputs unchanged; every new file in ``work`` lies under the ``--out`` the user named."""
    assert snapshot(inputs) == before, "an input file was changed or added"
    named = (work / out_token).resolve() if out_token and out_token.strip() else None
    for p in work.rglob("*"):
        if not p.is_file():
            continue
        rp = p.resolve()
        assert named is not None and (rp == named or rp.is_relative_to(named)), \
            f"{p} was written outside the named output {out_token!r}"
