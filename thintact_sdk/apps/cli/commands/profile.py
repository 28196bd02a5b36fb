"""``thintact profile validate FILE`` and ``thintact profile show NAME``."""

from __future__ import annotations

import argparse
import json

import yaml

from thintact_sdk.device.plugin_check import check_profile_plugins
from thintact_sdk.formats.profiles import available_profiles, load_profile, read_profile_file


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("profile", help="validate, show and list device profiles")
    psub = p.add_subparsers(dest="profile_command", metavar="ACTION", required=True)
    v = psub.add_parser("validate", help="validate profile files (JSON or YAML)")
    v.add_argument("files", nargs="+", metavar="FILE")
    v.add_argument("--strict", action="store_true",
                   help="also check that every plugin the profile names is installed")
    v.set_defaults(func=run_validate)
    s = psub.add_parser("show", help="print a profile by name or file")
    s.add_argument("name", metavar="NAME")
    s.add_argument("--json", action="store_true", help="print JSON instead of YAML")
    s.set_defaults(func=run_show)
    ls = psub.add_parser("list", help="list the profiles found by name")
    ls.set_defaults(func=run_list)


def run_validate(args: argparse.Namespace) -> int:
    for f in args.files:
        prof = read_profile_file(f)  # raises ProfileError naming the field
        if args.strict:
            check_profile_plugins(prof)
        print(f"{f}: ok (profile {prof.name!r}, sensor {prof.sensor.rows}x{prof.sensor.cols}, "
              f"scene {prof.scene.rows}x{prof.scene.cols}, K={prof.mask.K})")
    return 0


def run_show(args: argparse.Namespace) -> int:
    prof = load_profile(args.name)
    d = prof.contract_dict()
    if args.json:
        print(json.dumps(d, indent=1))
    else:
        # phi lists are long: show them in flow style
        print(yaml.safe_dump(d, sort_keys=False, default_flow_style=None, width=100), end="")
    if prof.source:
        print(f"# from {prof.source}")
    return 0


def run_list(args: argparse.Namespace) -> int:
    for name, path in sorted(available_profiles().items()):
        print(f"{name:24s} {path}")
    return 0
