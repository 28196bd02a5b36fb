"""No core module names a plugin's component (issue 31).

The core reaches plugins through the registry, by the names profiles and users give and by
the traits components declare (:data:`thintact_sdk.hookspecs.TRAITS`); it never chooses a
camera, light controller, mask, display, decoder, command, benchmark or device lister of a
plugin by writing its name. This test loads every plugin under ``plugins/`` through its entry
point into a fresh registry, collects the names of the components each registers, and scans
every string constant of every core module (``thintact_sdk/**/*.py``, by ``ast``): a constant
equal to one of those names fails the test, which names ``module:line``.

The component kinds (:data:`thintact_sdk.hookspecs.KINDS`: ``mask``, ``camera`` ...) are the
core's own vocabulary and are not counted when a plugin happens to name a component after
one (the masks plugin's ``thintact mask`` command). :data:`ALLOWED` lists the few constants
that equal a component name by coincidence, each with its reason.
"""

from __future__ import annotations

import ast
import importlib
import tomllib
from pathlib import Path

from thintact_sdk.device.registry import PluginRegistry
from thintact_sdk.hookspecs import KINDS

ROOT = Path(__file__).resolve().parents[2]
CORE = ROOT / "thintact_sdk"
ALLOWED = {
    ("thintact_sdk/simulation/scenes.py", "random"): "the scene library's random scene, not the mask designer",
    ("thintact_sdk/tactile/calibration/device.py", "virtual"): "a LUT's provenance label (calibrated on the "
                                                               "virtual sensor), not a component choice",
}
"""``(core module, constant)`` pairs that equal a plugin component's name, and why allowed."""


def plugin_component_names() -> dict[str, str]:
    """Component name → ``plugin kind`` for every component the plugins under ``plugins/``
    register, each loaded from its own entry points (``[project.entry-points.thintact]``)."""
    registry = PluginRegistry()
    for pyproject in sorted((ROOT / "plugins").glob("*/pyproject.toml")):
        project = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]
        for name, target in project.get("entry-points", {}).get("thintact", {}).items():
            module, _, attr = target.partition(":")
            obj = importlib.import_module(module.strip())
            registry.register(getattr(obj, attr.strip()) if attr else obj, name)
    names: dict[str, str] = {}
    for plugin, info in registry.plugins.items():
        assert info.error is None, f"plugin {plugin} did not load: {info.error}"
        for kind, provided in info.provides.items():
            for comp in provided:
                names.setdefault(comp, f"{plugin} {kind}")
    return names


def core_strings() -> list[tuple[str, int, str]]:
    """``(module path, line, value)`` of every string constant in the core's modules."""
    found = []
    for path in sorted(CORE.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                found.append((str(path.relative_to(ROOT)), node.lineno, node.value))
    return found


def test_the_plugins_register_components() -> None:
    names = plugin_component_names()
    assert {"uvc", "replay", "virtual"} <= set(names), "the scan needs the plugins' component names"


def test_every_allowed_exception_is_still_there() -> None:
    present = {(module, value) for module, _, value in core_strings()}
    assert set(ALLOWED) <= present, "remove the allowances that no longer match a constant"


def test_no_core_module_names_a_plugin_component() -> None:
    names = plugin_component_names()
    offenders = [f"{module}:{line}: {value!r} ({names[value]})"
                 for module, line, value in core_strings()
                 if value in names and value not in KINDS and (module, value) not in ALLOWED]
    assert offenders == [], "core modules name plugin components:\n" + "\n".join(offenders)
