"""The public modules plugins import (``thintact_sdk.algorithms``, ``thintact_sdk.plugin_support``)
load every name they list, lazily, and declare each to type checkers (issue 31): a name missing
from the ``TYPE_CHECKING`` block would be ``Any`` to mypy in every plugin."""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

MODULES = ("thintact_sdk.algorithms", "thintact_sdk.plugin_support")


def _declared_for_type_checkers(module: str) -> set[str]:
    path = Path(importlib.import_module(module).__file__ or "")
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for imp in node.body:
                if isinstance(imp, ast.ImportFrom):
                    names.update(a.asname or a.name for a in imp.names)
    return names


@pytest.mark.parametrize("module", MODULES)
def test_every_public_name_is_declared_for_type_checkers(module: str) -> None:
    mod = importlib.import_module(module)
    assert set(mod.__all__) == _declared_for_type_checkers(module)


@pytest.mark.parametrize("module", MODULES)
def test_every_public_name_loads(module: str) -> None:
    mod = importlib.import_module(module)
    for name in mod.__all__:
        assert getattr(mod, name) is not None, name


@pytest.mark.parametrize("module", MODULES)
def test_importing_the_module_loads_nothing_heavy(module: str) -> None:
    """Lazy: importing it pulls in neither torch nor the simulator."""
    code = (f"import sys, {module}; "
            "print(sorted(m for m in ('torch', 'thintact_sdk.simulation.simulator') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
