"""``thintact diagnose-tactile PACK --out DIR``: compare real tactile press frames with the
tactile simulation of the same presses, name the effects it leaves out, fit them and show the
fit improve (report.json, report.html, fitted_tactile.yaml)."""

from __future__ import annotations

import argparse
import time

from thintact_sdk.apps.cli.argtypes import int_range, positive_float
from thintact_sdk.apps.cli.output_path import add_force_argument, claim_output


def _indices(text: str) -> list[int] | str:
    if text in ("all", "even"):
        return text
    try:
        return [int(t) for t in text.split(",") if t.strip()]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"'all', 'even' or press indices: {text!r}") from exc


def _effects(text: str) -> tuple[str, ...]:
    from thintact_sdk.diagnosis.tactile.vocabulary import DEFAULT_EFFECTS, VOCABULARY

    add = text.startswith("+")
    names = [t.strip() for t in text.lstrip("+").split(",") if t.strip()]
    unknown = [n for n in names if n not in VOCABULARY]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"unknown effect(s) {', '.join(unknown) or '(none given)'}; the vocabulary: "
            f"{', '.join(VOCABULARY)}")
    return tuple(dict.fromkeys((DEFAULT_EFFECTS if add else ()) + tuple(names)))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("diagnose-tactile",
                       help="name and fit what the tactile simulation misses on real presses",
                       description=__doc__)
    p.add_argument("pack", metavar="RECORDING_OR_PACK",
                   help="press pack (.npz with imgs P×H×W×3 and f0, e.g. Taxim's dataPack) "
                   "or a directory holding one")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--ball-radius-mm", type=positive_float, default=2.0,
                   help="radius of the pressed ball, mm (default 2.0: Taxim's GelSight pack)")
    p.add_argument("--mm-per-px", type=positive_float, default=0.1245,
                   help="image pixel size, mm (default 0.1245)")
    p.add_argument("--presses", type=_indices, default=None, metavar="all|even|I,J,…",
                   help="presses to use (default all)")
    p.add_argument("--max-effects", type=int_range(0, 8), default=8,
                   help="accept at most K effects (default 8)")
    p.add_argument("--effects", type=_effects, default=None, metavar="NAME,…|+NAME,…",
                   help="effects to try (default: the vocabulary but the opt-in gel_sink_in); "
                   "'+NAME,…' adds to the default")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_force_argument(p, "into an existing non-empty --out")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from thintact_sdk.diagnosis.tactile.from_pack import diagnose_tactile_pack
    from thintact_sdk.diagnosis.tactile.press_engine import TactileDiagnosisOptions
    from thintact_sdk.diagnosis.tactile.report import write_tactile_outputs
    from thintact_sdk.diagnosis.tactile.vocabulary import DEFAULT_EFFECTS
    from thintact_sdk.host.progress import stage_reporter

    out = claim_output(args.out, "directory", force=args.force, inputs=(args.pack,))
    con = Console(stderr=True, quiet=args.quiet)
    t0 = time.perf_counter()
    with stage_reporter(args.quiet) as say:  # lines also when stderr is a file or a pipe
        d = diagnose_tactile_pack(args.pack, args.ball_radius_mm, args.mm_per_px, args.presses,
                                  TactileDiagnosisOptions(max_effects=args.max_effects,
                                                          effects=args.effects or DEFAULT_EFFECTS),
                                  progress=say, log=con.print)
    rep = d.report
    paths = write_tactile_outputs(d, out)
    print(f"noise {rep['noise_rms_dn']} DN; baseline chi2/dof {rep['baseline']['chi2_per_dof']:.3f}")
    for f in rep["findings"]:
        alt = f" (or: {', '.join(f['alternatives'])})" if f["alternatives"] else ""
        print(f"  + {f['effect']}{alt}: chi2/dof {f['chi2_per_dof_after']:.3f}  {f['params']}")
    print(f"final chi2/dof {rep['final']['chi2_per_dof']:.3f}")
    if rep["unexplained"]["significant"]:
        print(f"unexplained: {rep['unexplained']['summary']}")
    print(f"wrote {paths['report']}, {paths['html']}, {paths['fitted_profile']} "
          f"in {time.perf_counter() - t0:.1f} s")
    return 0
