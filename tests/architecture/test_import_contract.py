"""The one-way border (docs/architecture.md): the core never imports a plugin package, and the
core's modules import each other without cycles (function-local and ``TYPE_CHECKING`` imports
count: a cycle hidden behind them is still a cycle).

The plugin packages are found on disk (every ``plugins/*/<package>/__init__.py``), so a new
plugin is covered without editing this test; ``lint-imports`` (pyproject ``[tool.importlinter]``)
runs the same forbidden contract in ``make lint``.
"""

from __future__ import annotations

import sys
import textwrap
from collections.abc import Iterable, Mapping
from pathlib import Path

import grimp
import pytest

ROOT = Path(__file__).resolve().parents[2]


def plugin_packages() -> list[str]:
    """Top-level packages of every plugin distribution under ``plugins/``."""
    found = sorted({init.parent.name for init in ROOT.glob("plugins/*/*/__init__.py")})
    assert found, "no plugin packages found under plugins/"
    return found


def import_cycles(edges: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative).

    Parameters
    ----------
    edges
        ``importer -> modules it imports directly``.

    Returns
    -------
    list of list of str
        Each cycle's modules, sorted; empty when the graph is acyclic.
    """
    graph = {v: sorted(set(ws) & set(edges)) for v, ws in edges.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    cycles: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, 0)]
        while work:
            v, i = work.pop()
            if i == 0:
                index[v] = low[v] = counter
                counter += 1
                stack.append(v)
                on_stack.add(v)
            children = graph[v]
            if i < len(children):
                work.append((v, i + 1))
                w = children[i]
                if w not in index:
                    work.append((w, 0))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            for w in children:  # after all children: fold in their low-links
                if w in on_stack:
                    low[v] = min(low[v], low[w])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    cycles.append(sorted(comp))
    return cycles


def module_edges(graph: grimp.ImportGraph, package: str) -> dict[str, set[str]]:
    mods = {m for m in graph.modules if m == package or m.startswith(package + ".")}
    return {m: set(graph.find_modules_directly_imported_by(m)) & mods for m in mods}


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph("thintact_sdk", *plugin_packages(),
                             exclude_type_checking_imports=False, cache_dir=None)


def test_the_core_imports_no_plugin_package(graph: grimp.ImportGraph) -> None:
    offending = []
    for plugin in plugin_packages():
        for chain in graph.find_shortest_chains(importer="thintact_sdk", imported=plugin):
            offending.append(" -> ".join(chain))
    assert not offending, "the core imports plugin code:\n" + "\n".join(offending)


def test_the_core_has_no_import_cycle(graph: grimp.ImportGraph) -> None:
    cycles = import_cycles(module_edges(graph, "thintact_sdk"))
    assert cycles == [], f"import cycles in the core: {cycles}"


def test_the_checks_catch_a_cycle_and_a_plugin_import(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The same checks on a throw-away core that breaks both rules (so they can fail)."""
    core, plugin = tmp_path / "toycore", tmp_path / "toyplugin"
    core.mkdir()
    plugin.mkdir()
    (core / "__init__.py").write_text("")
    (core / "a.py").write_text("def f():\n    from toycore import b\n    return b\n")
    (core / "b.py").write_text(textwrap.dedent("""\
        from typing import TYPE_CHECKING
        if TYPE_CHECKING:
            from toycore.a import f
        import toyplugin.thing
        """))
    (plugin / "__init__.py").write_text("")
    (plugin / "thing.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    toy = grimp.build_graph("toycore", "toyplugin", exclude_type_checking_imports=False,
                            cache_dir=None)
    assert import_cycles(module_edges(toy, "toycore")) == [["toycore.a", "toycore.b"]]
    assert toy.find_shortest_chains(importer="toycore", imported="toyplugin")
    for name in [m for m in sys.modules if m.startswith(("toycore", "toyplugin"))]:
        del sys.modules[name]


def test_lint_imports_contract_holds() -> None:
    """``lint-imports`` (the pyproject contract, as ``make lint`` runs it) passes."""
    from importlinter.cli import lint_imports

    assert lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True) == 0


def test_the_public_algorithm_api_resolves_every_name_it_lists() -> None:
    """Every name plugins may import from ``thintact_sdk.algorithms`` loads (lazily) and is the
    implementing module's object; an unknown name is an AttributeError."""
    import importlib

    api = importlib.import_module("thintact_sdk.algorithms")
    for name in api.__all__:
        value = getattr(api, name)
        assert value is not None, name
    from thintact_sdk.reconstruction.t2s import SystemMatrices

    assert api.SystemMatrices is SystemMatrices
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        api.nope  # noqa: B018
