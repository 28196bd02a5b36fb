"""Parsing untrusted JSON (a recording manifest, a bundle's ``meta_json``, a design file) with
bounded nesting.

:func:`json.loads` recurses once per nesting level: a file nested a hundred thousand deep
raises :class:`RecursionError`, and one nested just below the interpreter's limit parses but
makes every later recursive walk (validation, ``json.dumps`` when the data is written back)
fail the same way. :func:`loads` turns both into the caller's
:class:`~thintact_sdk.errors.ThinTactError` naming the file, refusing nesting deeper than
:data:`MAX_DEPTH`.
"""

from __future__ import annotations

import json
from typing import Any

from thintact_sdk.errors import ThinTactError

MAX_DEPTH = 64
"""Deepest nesting of arrays/objects accepted (the SDK's own files nest a few levels)."""


def nesting_depth(value: Any, stop: int = MAX_DEPTH) -> int:
    """Nesting depth of lists/dicts in ``value`` (a scalar is 0, ``[]`` is 1), without
    recursion; counting stops just past ``stop``."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            children: Any = item.values()
        elif isinstance(item, list | tuple):
            children = item
        else:
            continue
        depth += 1
        if depth > deepest:
            deepest = depth
            if deepest > stop:
                return deepest
        stack.extend((c, depth) for c in children if isinstance(c, dict | list | tuple))
    return deepest


MAX_INT_DIGITS = 308
"""Longest integer a JSON file may hold: every number the SDK reads is used as a float, and
float64 ends at 1.8e308 (a 309-digit integer gave OverflowError wherever it was used)."""


def _parse_int(text: str) -> int:
    digits = len(text) - text.startswith("-")
    if digits > MAX_INT_DIGITS:
        raise ValueError(f"an integer of {digits} digits, beyond any number this SDK reads "
                         f"(at most {MAX_INT_DIGITS})")
    return int(text)


def loads(text: str | bytes, where: object, error: type[ThinTactError] = ThinTactError,
          max_depth: int = MAX_DEPTH) -> Any:
    """``json.loads(text)`` for the file ``where``.

    Raises
    ------
    error
        Naming ``where``: invalid JSON, undecodable bytes, an integer of more than
        :data:`MAX_INT_DIGITS` digits, or nesting deeper than ``max_depth``.
    """
    try:
        value = json.loads(text, parse_int=_parse_int)
    except ValueError as err:
        if isinstance(err, json.JSONDecodeError | UnicodeDecodeError):
            raise error(f"{where}: invalid JSON ({err})") from None
        raise error(f"{where}: {str(err).split(';')[0]}") from None
    except RecursionError:
        raise error(f"{where}: JSON nested too deeply (more than the interpreter's recursion "
                    f"limit; at most {max_depth} levels are read)") from None
    depth = nesting_depth(value, max_depth)
    if depth > max_depth:
        raise error(f"{where}: JSON nested more than {max_depth} levels deep; refused")
    return value
