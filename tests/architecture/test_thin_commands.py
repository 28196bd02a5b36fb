"""Thin commands (issue 31): a CLI command parses, calls one library function and prints.

An AST check over ``thintact_sdk/apps/cli/commands/*.py``: no function there may hold more
than :data:`MAX_STATEMENTS` *working statements*, so logic does not creep back into the
commands. A working statement is any statement in the function's body, nested blocks
included, except imports, docstrings and bare ``print(...)`` calls (a command prints as much
as it likes; the ``if`` or ``for`` around a print still counts). The argument parsers
(``register``) and the print helpers (``_print*``, ``print_*``) are not checked.

Why :data:`MAX_STATEMENTS` = 25: the commands that only parse, call one library function and
print count 10 to 25 (``demo`` 12, ``simulate`` 10, ``doctor`` and ``diagnose-tactile`` about
11, ``diagnose`` 24 with its conditional report lines, ``tactile evaluate`` 25 with its
``--train`` parsing and report). The logic this part moved out of the commands counted 29 to
44 (``simulate`` 29, ``calibrate``'s wizard 32, ``demo`` 37, ``tactile depth`` 44): a loop over
frames or a second pipeline stage pushes a command over 25. :data:`KNOWN` lists the
functions still over it, each with what should move; :func:`test_every_known_exception_is_still_needed`
makes the list shrink as they move.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
COMMANDS = ROOT / "thintact_sdk" / "apps" / "cli" / "commands"
MAX_STATEMENTS = 25
"""The most working statements one function of a command module may hold (see the module docstring)."""
KNOWN: dict[tuple[str, str], str] = {}
"""``(module, function)`` pairs over the limit today, and what should move out of them."""


def _is_print(stmt: ast.stmt) -> bool:
    """A docstring or a bare ``print(...)`` / ``x.print(...)`` call."""
    if not isinstance(stmt, ast.Expr):
        return False
    v = stmt.value
    if isinstance(v, ast.Constant) and isinstance(v.value, str):
        return True
    if isinstance(v, ast.Call):
        f = v.func
        return (f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else "") == "print"
    return False


def _exempt(name: str) -> bool:
    """The parser and the print helpers."""
    return name == "register" or name.startswith(("_print", "print_"))


def working_statements(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Statements in ``fn``'s body (nested blocks and nested functions included), less
    imports, docstrings and bare print calls."""
    return sum(isinstance(s, ast.stmt) and not isinstance(s, ast.Import | ast.ImportFrom) and not _is_print(s)
               for s in ast.walk(fn)) - 1  # fn itself


def long_functions(source: str) -> dict[str, int]:
    """Top-level and nested functions of ``source`` (not exempt) over :data:`MAX_STATEMENTS`:
    name → working statements."""
    out = {}
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not _exempt(node.name):
            n = working_statements(node)
            if n > MAX_STATEMENTS:
                out[node.name] = n
    return out


def _over_the_limit() -> dict[tuple[str, str], int]:
    found = {}
    for path in sorted(COMMANDS.glob("*.py")):
        for name, n in long_functions(path.read_text(encoding="utf-8")).items():
            found[(path.name, name)] = n
    return found


def test_no_command_function_holds_logic() -> None:
    bad = {k: n for k, n in _over_the_limit().items() if k not in KNOWN}
    listed = ", ".join(f"{m}:{f} ({n})" for (m, f), n in sorted(bad.items()))
    assert not bad, (f"command functions over {MAX_STATEMENTS} working statements (move the logic into the "
                     f"library, the command parses, calls one function and prints): {listed}")


def test_every_known_exception_is_still_needed() -> None:
    assert set(KNOWN) <= set(_over_the_limit()), "remove the KNOWN entries that are now under the limit"


def test_the_check_catches_a_loop_and_spares_prints_and_parsers() -> None:
    body = "\n".join(f"        x{i} = i * {i}" for i in range(MAX_STATEMENTS))
    loop = f"def run(args):\n    for i in range(3):\n{body}\n"
    assert long_functions(loop) == {"run": MAX_STATEMENTS + 1}
    prints = "def run(args):\n    import json\n    \"\"\"doc\"\"\"\n" + "".join(
        f"    print({i})\n" for i in range(3 * MAX_STATEMENTS))
    assert long_functions(prints) == {}
    parser = "def register(sub):\n" + "".join(f"    p{i} = {i}\n" for i in range(3 * MAX_STATEMENTS))
    assert long_functions(parser) == {} and long_functions(parser.replace("register", "_parse_frames"))
