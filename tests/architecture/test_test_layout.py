"""Where the tests live, as docs/architecture.md draws it (issue 31).

The core's tests are under ``tests/``; each plugin's tests are beside the plugin, in
``plugins/<plugin>/tests/`` (fixtures of their own in a ``conftest.py`` there; the private
cache every test shares in the repository's root ``conftest.py``), so a plugin is tested alone
(``python -m pytest plugins/<plugin>/tests``) and ``make test`` (pytest's ``testpaths``) still
runs everything. These tests fail when a plugin or a test folder is added, moved or removed
without the drawing, when a plugin's tests lean on the core's test helpers, or when two test
modules share a name (pytest's default import mode imports them by their bare name).
"""

from __future__ import annotations

import ast
import re
import tomllib
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "architecture.md"
TESTS = ROOT / "tests"


def _drawing() -> tuple[set[str], set[str]]:
    """``(folders under tests/, plugins)`` drawn in the test-layout block; a plugin is drawn
    with its ``tests/`` folder (``"thintact_uvc"`` when ``plugins/thintact_uvc/tests/`` is)."""
    text = DOC.read_text(encoding="utf-8")
    start = text.index("<!-- test-layout")
    block = text[text.index("```text", start) + len("```text"):]
    block = block[: block.index("```")]
    test_dirs: set[str] = set()
    plugins: set[str] = set()
    top = ""
    plugin = ""
    for line in block.splitlines():
        m = re.match(r"^( *)((?:\S+/ ?)+)", line)
        if m is None:
            continue
        depth = len(m.group(1)) // 2
        names = [n.rstrip("/") for n in m.group(2).split()]
        if depth == 0:
            top = names[0]
        elif top == "tests":
            test_dirs.update(names)
        elif top == "plugins" and depth == 1:
            plugin = names[0]
        elif top == "plugins" and depth == 2 and names == ["tests"]:
            plugins.add(plugin)
    return test_dirs, plugins


def _plugins_on_disk() -> set[str]:
    return {p.parent.name for p in (ROOT / "plugins").glob("*/pyproject.toml")}


def _test_files() -> list[Path]:
    files = list(TESTS.rglob("*.py")) + list((ROOT / "plugins").glob("*/tests/**/*.py"))
    return [f for f in files if "__pycache__" not in f.parts]


def test_the_drawing_is_the_tree() -> None:
    test_dirs, plugins = _drawing()
    on_disk = {p.name for p in TESTS.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert test_dirs == on_disk, "docs/architecture.md's test layout differs from tests/"
    assert plugins == _plugins_on_disk(), "docs/architecture.md's test layout differs from plugins/"


def test_every_plugin_has_its_tests_beside_it() -> None:
    for name in sorted(_plugins_on_disk()):
        tests = ROOT / "plugins" / name / "tests"
        assert list(tests.glob("test_*.py")), f"{tests}: no test modules"
        assert not (tests / "__init__.py").exists(), f"{tests}: a package would be shipped with the plugin"


def test_pytest_collects_the_core_and_the_plugin_tests() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert config["tool"]["pytest"]["ini_options"]["testpaths"] == ["tests", "plugins/*/tests"]


def test_no_two_test_modules_share_a_name() -> None:
    names = Counter(p.name for p in _test_files() if p.name not in ("conftest.py", "__init__.py"))
    assert [n for n, k in names.items() if k > 1] == []


def test_plugin_tests_do_not_import_the_core_tests_helpers() -> None:
    """A plugin's tests import the SDK, the plugin and their own helpers, never a module of
    ``tests/`` (which a plugin tested alone does not have)."""
    helpers = {p.stem for p in TESTS.rglob("*.py") if p.stem not in ("conftest", "__init__")}
    helpers |= {p.name for p in TESTS.iterdir() if (p / "__init__.py").is_file()}
    offenders = []
    for path in (ROOT / "plugins").glob("*/tests/**/*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                mods = [node.module]
            else:
                continue
            offenders += [f"{path.relative_to(ROOT)}: {m}" for m in mods if m.split(".")[0] in helpers]
    assert offenders == []


def test_the_drawing_is_read() -> None:
    """The parser sees the folders (a guard against a drawing the tests silently skip)."""
    test_dirs, plugins = _drawing()
    assert {"architecture", "calibration", "viewer"} <= test_dirs
    assert {"thintact_uvc", "thintact_masks"} <= plugins


def test_every_test_gets_the_private_cache() -> None:
    """The root conftest.py (loaded for ``tests/`` and every ``plugins/*/tests``, alone or
    together) sends the per-host caches to a session directory."""
    text = (ROOT / "conftest.py").read_text(encoding="utf-8")
    assert "autouse=True" in text and "def _private_user_cache" in text
    assert not any("def _private_user_cache" in p.read_text(encoding="utf-8")
                   for p in [*TESTS.rglob("conftest.py"), *(ROOT / "plugins").glob("*/tests/conftest.py")])
