"""``thintact plugins``: what is installed and what each plugin provides."""

from __future__ import annotations

import argparse
import json

from thintact_sdk.device.registry import get_registry


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help="list installed plugins and what each provides")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--traceback", action="store_true", help="show import tracebacks of failed plugins")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    reg = get_registry()
    if args.json:
        out = {
            name: {
                "module": info.module,
                "distribution": info.distribution,
                "version": info.version,
                "provides": info.provides,
                "error": info.error,
            }
            for name, info in sorted(reg.plugins.items())
        }
        print(json.dumps(out, indent=1))
        return 0
    if not reg.plugins:
        print("no plugins installed (entry-point group 'thintact')")
        return 0
    for name, info in sorted(reg.plugins.items()):
        dist = f"{info.distribution} {info.version}" if info.distribution else info.module
        status = "FAILED" if info.error and not info.provides else "ok"
        print(f"{name}  [{status}]  ({dist})")
        for kind, comps in sorted(info.provides.items()):
            for c in comps:
                desc = reg.components(kind)[c].description
                print(f"    {kind:17s} {c:24s} {desc}")
        if info.error:
            print(f"    error: {info.error}")
            if args.traceback and getattr(info, "traceback", None):
                print(info.traceback)  # type: ignore[attr-defined]
    return 0
