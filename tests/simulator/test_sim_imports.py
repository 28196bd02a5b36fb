"""The kernel builders do not import the simulator that dispatches to them (no cycle, not
even one hidden behind ``TYPE_CHECKING`` or a function-local import)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import thintact_sdk.simulation as simulation

KERNEL_MODULES = ("params", "direct", "rotated", "refracted", "refracted_blocked", "separable",
                  "axis", "radiometry")


def _imports(path: Path) -> set[str]:
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return found


@pytest.mark.parametrize("name", KERNEL_MODULES)
def test_kernel_module_does_not_import_the_simulator(name: str) -> None:
    path = Path(simulation.__file__).parent / f"{name}.py"
    assert "thintact_sdk.simulation.simulator" not in _imports(path)


def test_direct_kernel_module_imports_on_its_own() -> None:
    code = "import thintact_sdk.simulation.direct as d; print(d.KernelParams.__module__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "thintact_sdk.simulation.params"
