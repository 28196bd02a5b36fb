"""The floor plan drawn in docs/architecture.md is the tree on disk (issue 31).

The drawing lists every package of ``thintact_sdk`` (and the shipped ``data/`` directory) and
every module at the top, the public surface. These tests fail when a package or top-level
module is added, moved or removed without the drawing, when two modules share a name, or when
a file-name prefix stands in for a package.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "thintact_sdk"
DOC = ROOT / "docs" / "architecture.md"
PREFIXES = ("sim_", "recon_", "diag_", "tac_", "cal_")
"""File-name prefixes that stood in for packages before the floor plan."""


def _drawing() -> tuple[set[str], set[str]]:
    """``(directories, top-level modules)`` drawn in the floor-plan block, as paths relative
    to ``thintact_sdk/`` (``"tactile/simulation"``, ``"errors.py"``)."""
    text = DOC.read_text(encoding="utf-8")
    start = text.index("<!-- floor-plan")
    block = text[text.index("```text", start) + len("```text"):]
    block = block[: block.index("```")]
    dirs: set[str] = set()
    modules: set[str] = set()
    stack: list[str] = []
    for line in block.splitlines():
        m = re.match(r"^( *)(\S+)", line)
        if m is None or m.group(2) == "thintact_sdk/":
            continue
        depth = len(m.group(1)) // 2 - 1
        name = m.group(2)
        stack = stack[:depth]
        if name.endswith("/"):
            stack.append(name.rstrip("/"))
            dirs.add("/".join(stack))
        elif name.endswith(".py"):
            assert depth == 0, f"the drawing lists modules at the top only: {line!r}"
            modules.add(name)
    return dirs, modules


def _packages() -> set[str]:
    return {str(p.parent.relative_to(PKG)) for p in PKG.rglob("__init__.py")
            if p.parent != PKG and "__pycache__" not in p.parts}


def test_every_package_on_disk_is_drawn_and_every_drawn_one_exists() -> None:
    dirs, _ = _drawing()
    packages = _packages()
    assert packages - dirs == set(), "packages missing from docs/architecture.md's floor plan"
    missing = {d for d in dirs if not (PKG / d).is_dir()}
    assert missing == set(), "the floor plan draws directories that do not exist"
    assert dirs - packages <= {"data"}, "only data/ is a directory that is not a package"


def test_the_public_surface_is_the_drawn_top_level_modules() -> None:
    _, modules = _drawing()
    on_disk = {p.name for p in PKG.glob("*.py")}
    assert on_disk == modules


def test_no_two_modules_share_a_name() -> None:
    names = Counter(p.name for p in PKG.rglob("*.py")
                    if p.name != "__init__.py" and "__pycache__" not in p.parts)
    assert [n for n, k in names.items() if k > 1] == []


def test_no_file_name_prefix_stands_in_for_a_package() -> None:
    offenders = [str(p.relative_to(PKG)) for p in PKG.rglob("*.py")
                 if p.name.startswith(PREFIXES) or p.stem.startswith(f"{p.parent.name}_")]
    assert offenders == []


def test_the_drawing_is_read() -> None:
    """The parser sees the roles (a guard against a drawing the tests silently skip)."""
    dirs, modules = _drawing()
    assert {"device", "formats", "simulation/effects", "tactile/interpretation", "apps/cli"} <= dirs
    assert {"__init__.py", "errors.py", "algorithms.py"} <= modules
