"""A profile's YAML text with only its ``mask`` section rewritten (``thintact mask apply``).

Everything outside the top-level ``mask:`` section (comments, key order, flow or block style,
blank lines) is kept byte for byte. The section itself is rewritten from the new mask
fields, in the profile's key order, lists in flow style (``phi: [1, -1, ...]``, wrapped at
:data:`WRAP` characters); the full-line comments that were inside it are kept at its top,
and a comment on the ``mask:`` line stays there. The caller validates the result by parsing it.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

WRAP = 100
"""Longest line of a rewritten flow list (characters; longer lists continue on indented lines)."""
_INDENT = "  "
_MASK_LINE = re.compile(r"^mask\s*:(\s*(#.*)?)?$")
_MASK_ANY = re.compile(r"^mask\s*:")


def _scalar(value: Any) -> str:
    text = yaml.safe_dump(value, default_flow_style=True, width=10**9, sort_keys=False).strip()
    return text[:-3].strip() if text.endswith("\n...") or text.endswith("...") else text


def _flow_list(key: str, values: list[Any]) -> list[str]:
    items = [_scalar(v) for v in values]
    head = f"{_INDENT}{key}: ["
    lines, line = [], head
    for n, item in enumerate(items):
        piece = item + (", " if n < len(items) - 1 else "]")
        if len(line) + len(piece.rstrip()) > WRAP and line.strip() not in (f"{key}: [",):
            lines.append(line.rstrip())
            line = _INDENT * 2 + piece
        else:
            line += piece
    if not items:
        line += "]"
    lines.append(line.rstrip())
    return lines


def render_mask(mask: dict[str, Any]) -> list[str]:
    """The ``mask`` fields as block-style lines (two-space indent), lists in flow style."""
    out: list[str] = []
    for key, value in mask.items():
        if isinstance(value, list):
            out += _flow_list(key, value)
        else:
            out.append(f"{_INDENT}{key}: {_scalar(value)}")
    return out


def replace_mask_section(text: str, mask: dict[str, Any]) -> str | None:
    """``text`` with its top-level ``mask:`` section replaced by ``mask`` (module docstring);
    None when the text has no top-level ``mask:`` key this edit can find."""
    lines = text.splitlines()
    start = next((i for i, ln in enumerate(lines) if _MASK_ANY.match(ln)), None)
    if start is None:
        return None
    nxt = next((i for i in range(start + 1, len(lines))
                if lines[i].strip() and not lines[i][0].isspace() and not lines[i].startswith("#")),
               len(lines))
    end = start + 1
    for i in range(start + 1, nxt):
        if lines[i].strip() and lines[i][0].isspace():
            end = i + 1
    m = _MASK_LINE.match(lines[start])
    comment = m.group(1).rstrip() if m and m.group(1) else ""
    kept = [ln for ln in lines[start + 1:end] if ln.strip().startswith("#")]
    new = [f"mask:{comment}", *kept, *render_mask(mask)]
    tail = "\n" if text.endswith("\n") else ""
    return "\n".join(lines[:start] + new + lines[end:]) + tail
