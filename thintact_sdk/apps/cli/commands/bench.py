"""``thintact bench NAME``: the core's benchmarks (:mod:`thintact_sdk.apps.benchmarks`) and those plugins
contribute through the ``thintact_benchmarks`` hook (e.g. ``reconstruct`` from the decoders plugin)."""

from __future__ import annotations

import argparse
import importlib
import pkgutil

import thintact_sdk.apps.benchmarks as benchmarks
from thintact_sdk.device.registry import get_registry
from thintact_sdk.errors import PluginError, ThinTactError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run a benchmark and print its figures")
    bsub = p.add_subparsers(dest="bench_name", metavar="NAME", required=True)
    for info in sorted(pkgutil.iter_modules(benchmarks.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{benchmarks.__name__}.{info.name}")
        if not (hasattr(mod, "add_arguments") and hasattr(mod, "run")):
            continue  # a helper of the benchmarks, not one itself
        doc = (mod.__doc__ or info.name).strip().splitlines()[0]
        bp = bsub.add_parser(getattr(mod, "NAME", info.name), help=doc, description=mod.__doc__)
        mod.add_arguments(bp)
        bp.set_defaults(func=mod.run)
    try:
        contributed = get_registry().components("benchmark")
    except ThinTactError:  # a broken plugin set still leaves the core's benchmarks
        contributed = {}
    for name, comp in sorted(contributed.items()):
        bp = bsub.add_parser(name, help=comp.description, description=comp.description)
        try:
            get_registry().create("benchmark", name, bp)
        except ThinTactError:  # recorded on its plugin; the benchmark says so when run
            bp.set_defaults(func=_broken(name))


def _broken(name: str):  # noqa: ANN202 - an argparse handler
    def run(args: argparse.Namespace) -> int:
        raise PluginError(f"benchmark {name!r} failed to build; `thintact plugins` shows why")
    return run
