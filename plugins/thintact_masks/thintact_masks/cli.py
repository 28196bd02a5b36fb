"""``thintact mask ...``: design, optimise (GA), show, compare and apply mask patterns.

The designs come from the ``mask`` plugins (``thintact-masks``: ``mls``, ``random``, ``ga``).
This plugin contributes the command to the core CLI through the ``thintact_cli_commands``
hook; the core knows nothing of it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from thintact_sdk.errors import ThinTactError
from thintact_sdk.plugin_support import (
    add_force_argument,
    check_not_an_input,
    claim_output,
    file_input,
    fraction,
    int_range,
    non_negative_int,
    positive_float,
    positive_int,
    seed,
)

MAX_PNG_SIDE_PX = 16384
"""Largest side of the image ``mask show`` renders (K × cell px), checked before allocating."""


def _plugin() -> Any:
    import thintact_masks

    return thintact_masks


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("mask", help="design, optimise (GA), show and compare mask patterns")
    msub = p.add_subparsers(dest="mask_command", metavar="ACTION", required=True)

    o = msub.add_parser("optimize", help="optimise phi for a device with the paper's GA",
                        description="Genetic-algorithm mask optimisation (paper III-C). Writes "
                        "DIR/checkpoint.npz every generation; re-running with the same DIR and "
                        "settings resumes. Writes DIR/design.json and DIR/fitness.png.")
    o.add_argument("--profile", required=True, help="device profile name or file")
    o.add_argument("--out", required=True, metavar="DIR", help="output and checkpoint directory")
    o.add_argument("--population", type=int_range(2), default=200, help="individuals, >= 2 (paper 200)")
    o.add_argument("--generations", type=non_negative_int, default=2000, help="generations (paper 2000)")
    o.add_argument("--K", type=int_range(2), default=None, help="mask length, >= 2 (default: the profile's)")
    o.add_argument("--seed", type=seed, default=0, help="random seed, 0..2**63-1")
    o.add_argument("--scale", type=fraction, default=1.0,
                   help="optimise on a self-similar scaled-down device (0 < scale <= 1)")
    o.add_argument("--frames", type=positive_int, default=100,
                   help="frames averaged per simulated measurement (noise; paper 100)")
    o.add_argument("--noise-free", action="store_true", help="simulate without sensor noise")
    o.add_argument("--tau", type=positive_float, default=None,
                   help="Tikhonov weight in relative-irradiance units (default: Wiener value)")
    o.add_argument("--float32", action="store_true", help="single precision eigen-decompositions")
    o.add_argument("--workers", type=positive_int, default=None,
                   help="individuals evaluated at once, one BLAS thread each (default 1; with "
                   "--ray auto: CPUs of the local cluster, default all); result unchanged")
    o.add_argument("--ray", nargs="?", const="auto", default=None, metavar="ADDRESS",
                   help="evaluate each generation's individuals as Ray tasks: on a private "
                   "local cluster (--ray or --ray auto) or on the cluster at ADDRESS "
                   "(HOST:6379 or ray://HOST:10001); result unchanged")
    o.add_argument("--ray-batch", type=positive_int, default=None, metavar="N",
                   help="individuals per Ray task (default: about two tasks per worker)")
    o.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto",
                   help="fitness on torch CUDA (cuda), numpy (cpu) or CUDA when present (auto)")
    o.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_force_argument(o, "into an existing non-empty --out that holds no checkpoint to resume")
    o.set_defaults(func=run_optimize)

    s = msub.add_parser("show", help="render a design's K x K pattern as a PNG")
    s.add_argument("design", metavar="DESIGN.json")
    s.add_argument("--out", required=True, metavar="PNG")
    s.add_argument("--cell-px", type=int_range(1, MAX_PNG_SIDE_PX), default=1,
                   help=f"image pixels per mask cell (the image is at most {MAX_PNG_SIDE_PX} px a side)")
    add_force_argument(s, "over an existing --out file")
    s.set_defaults(func=run_show)

    c = msub.add_parser("compare", help="white uniformity, PSNR, SSIM and fitness of designs "
                        "vs the MLS and random baselines on a device")
    c.add_argument("designs", nargs="*", metavar="DESIGN.json")
    c.add_argument("--profile", required=True)
    c.add_argument("--K", type=int_range(2), default=None,
                   help="baseline mask length, >= 2 (default: profile's)")
    c.add_argument("--scale", type=fraction, default=1.0,
                   help="compare on a scaled-down device (0 < scale <= 1)")
    c.add_argument("--frames", type=positive_int, default=100, help="frames averaged (noise), >= 1")
    c.add_argument("--exact", action="store_true",
                   help="also score with the exact simulator's coding matrices")
    c.add_argument("--json", action="store_true", help="machine-readable output")
    c.set_defaults(func=run_compare)

    d = msub.add_parser("design", help="write a design file from the mls or random designer")
    d.add_argument("--kind", default="mls", help="mask plugin component (mls, random)")
    d.add_argument("--K", type=positive_int, required=True, help="mask length, >= 1")
    d.add_argument("--feature-um", type=positive_float, required=True, help="feature size, um, > 0")
    d.add_argument("--seed", type=seed, default=0, help="random seed, 0..2**63-1")
    d.add_argument("--out", required=True, metavar="DESIGN.json")
    add_force_argument(d, "over an existing --out file")
    d.set_defaults(func=run_design)

    im = msub.add_parser("import", help="read a mask drawn elsewhere (PNG, DXF, CSV, NPY) into a design file",
                         description="A K x K pattern (open cells bright unless --open-dark; a drawing "
                         "with several pixels per cell needs --K), a DXF drawing (closed polylines, "
                         "solids or hatches are the open cells unless --open-dark; K from --K or the "
                         "drawing's units and --feature-um) or two +-1 vectors (phi, phi_rows) "
                         "become phi and phi_rows, checked against the SDK's convention (open where "
                         "phi_rows[i]*phi[j] = +1); a pattern that is not separable is refused.")
    im.add_argument("pattern", type=Path, metavar="PATTERN.(png|dxf|csv|npy)")
    im.add_argument("--feature-um", type=positive_float, required=True, help="mask cell side, um, > 0")
    im.add_argument("--K", type=positive_int, help="cells per side of a drawing with several pixels per cell")
    im.add_argument("--open-dark", action="store_true", help="open (transparent) cells are the dark ones "
                    "(DXF: the drawn shapes are the closed cells)")
    im.add_argument("--layer", help="DXF: read this layer only (default: every layer)")
    im.add_argument("--out", required=True, metavar="DESIGN.json")
    add_force_argument(im, "over an existing --out file")
    im.set_defaults(func=run_import)

    a = msub.add_parser("apply", help="write a copy of a profile that uses a design's phi")
    a.add_argument("design", metavar="DESIGN.json")
    a.add_argument("--profile", required=True)
    a.add_argument("--out", required=True, metavar="PROFILE.yaml")
    add_force_argument(a, "over an existing --out file")
    a.set_defaults(func=run_apply)


def _fitness_settings(args: argparse.Namespace) -> Any:
    from thintact_masks.fitness import FitnessSettings

    if args.frames < 1:
        raise ThinTactError(f"--frames must be >= 1, got {args.frames}")
    if getattr(args, "tau", None) is not None and not args.tau > 0:
        raise ThinTactError(f"--tau must be > 0, got {args.tau}")
    return FitnessSettings(noise=not getattr(args, "noise_free", False),
                           frames_averaged=args.frames, tau=getattr(args, "tau", None),
                           dtype="float32" if getattr(args, "float32", False) else "float64")


def run_optimize(args: argparse.Namespace) -> int:
    _plugin()
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    from thintact_masks.ga import CHECKPOINT_NAME, GAConfig
    from thintact_masks.optimize import DESIGN_NAME, PLOT_NAME, optimize_mask
    from thintact_sdk.plugin_support import load_profile

    inputs = (file_input(args.profile),)
    if not (Path(args.out) / CHECKPOINT_NAME).is_file() or not str(args.out).strip():
        claim_output(args.out, "directory", force=args.force, inputs=inputs)
    else:  # the documented resume
        check_not_an_input(args.out, inputs)
    profile = load_profile(args.profile)
    if args.K is not None and args.K < 2:
        raise ThinTactError(f"--K must be at least 2, got {args.K}")
    config = GAConfig(population=args.population, generations=args.generations, seed=args.seed)
    config.validate(args.K if args.K is not None else profile.mask.K)
    if args.workers is not None and args.workers < 1:
        raise ThinTactError(f"--workers must be >= 1, got {args.workers}")
    if args.ray_batch is not None and args.ray_batch < 1:
        raise ThinTactError(f"--ray-batch must be >= 1, got {args.ray_batch}")
    if args.ray_batch is not None and args.ray is None:
        raise ThinTactError("--ray-batch needs --ray")
    settings = _fitness_settings(args)
    bar = Progress(TextColumn("[bold]GA[/]"), BarColumn(), MofNCompleteColumn(),
                   TextColumn("best {task.fields[best]:.4f}  mean {task.fields[mean]:.4f}"),
                   TimeRemainingColumn(), disable=args.no_progress)
    with bar:
        task = bar.add_task("ga", total=args.generations, best=float("nan"), mean=float("nan"))

        def progress(state: Any) -> None:
            bar.update(task, completed=state.generation, best=state.best_history[-1],
                       mean=state.mean_history[-1])

        _, rec = optimize_mask(profile, config, args.K, settings, args.scale, args.out, progress,
                               args.workers, args.ray, args.ray_batch, args.device)
    out = Path(args.out)
    base = rec["baselines"]
    print(f"best fitness {rec['fitness']:.4f} after {len(rec['history']['best']) - 1} generations "
          f"(MLS {base['mls']['fitness']:.4f}, random {base['random']['fitness']:.4f})")
    print(f"design: {out / DESIGN_NAME}\nplot:   {out / PLOT_NAME}")
    return 0


def run_show(args: argparse.Namespace) -> int:
    _plugin()
    from thintact_masks.design_io import load_design, render_mask_png

    out = claim_output(args.out, "file", force=args.force, inputs=(args.design,))
    mask, _ = load_design(args.design)
    side = mask.K * args.cell_px
    if side > MAX_PNG_SIDE_PX:
        raise ThinTactError(f"--cell-px {args.cell_px}: the {mask.K}x{mask.K} mask would render a "
                            f"{side}x{side} px image; the limit is {MAX_PNG_SIDE_PX} px a side "
                            f"(--cell-px <= {max(MAX_PNG_SIDE_PX // mask.K, 1)})")
    path = render_mask_png(mask, out, args.cell_px)
    print(f"{path}: {mask.K}x{mask.K} cells ({mask.design}), open fraction "
          f"{float(mask.pattern().mean()):.3f}")
    return 0


def run_compare(args: argparse.Namespace) -> int:
    _plugin()
    import numpy as np

    from thintact_masks.compare import score_masks, score_masks_exact
    from thintact_masks.design_io import load_design
    from thintact_masks.devices import scaled_profile
    from thintact_masks.optimize import baseline_phi
    from thintact_sdk.interfaces import Mask
    from thintact_sdk.plugin_support import load_profile

    device = scaled_profile(load_profile(args.profile), args.scale)
    k = args.K if args.K is not None else device.mask.K
    if k < 2:
        raise ThinTactError(f"--K must be at least 2, got {k}")
    masks: dict[str, Mask] = {
        "mls": Mask(baseline_phi("mls", k), device.mask.feature_um, design="mls"),
        "random": Mask(baseline_phi("random", k, 1), device.mask.feature_um, design="random"),
    }
    for f in args.designs:
        mask, _ = load_design(f)
        masks[Path(f).stem if Path(f).stem != "design" else str(Path(f).parent.name)] = mask
    if args.scale == 1.0:  # a scaled device's own phi is only a placeholder
        masks.setdefault("profile", Mask(np.asarray(device.mask.phi, np.int8),
                                         device.mask.feature_um, design=device.mask.design or ""))
    settings = _fitness_settings(args)
    tables = {"direct generation": score_masks(device, masks, settings)}
    if args.exact:
        tables["exact simulator"] = score_masks_exact(device, masks, settings)
    if args.json:
        print(json.dumps({k: [s.as_dict() for s in v] for k, v in tables.items()}, indent=1))
        return 0
    for title, scores in tables.items():
        print(f"device {device.name}, {title} matrices: white-scene uniformity (1 - std/mean), "
              "PSNR (dB), SSIM, fitness")
        print(f"{'mask':24s} {'K':>5s} {'uniform':>8s} {'PSNRw':>7s} {'PSNRu':>7s} {'SSIMw':>6s} "
              f"{'SSIMu':>6s} {'fitness':>9s}")
        for s in scores:
            print(f"{s.name:24s} {masks[s.name].K:5d} {s.uniformity_white:8.4f} "
                  f"{s.psnr_white_db:7.2f} {s.psnr_usaf_db:7.2f} {s.ssim_white:6.3f} "
                  f"{s.ssim_usaf:6.3f} {s.fitness:9.3f}")
    return 0


def run_design(args: argparse.Namespace) -> int:
    _plugin()
    from thintact_masks.design_io import design_record, write_json_atomic
    from thintact_sdk.plugin_support import get_registry

    out = claim_output(args.out, "file", force=args.force)
    if args.kind == "ga":
        raise ThinTactError("use 'thintact mask optimize' for GA designs")
    if args.K < 1 or not args.feature_um > 0:
        raise ThinTactError("--K must be >= 1 and --feature-um > 0")
    designer = get_registry().create("mask", args.kind)
    mask = designer.design(args.K, args.feature_um, seed=args.seed)
    path = write_json_atomic(out, design_record(mask))
    print(f"{path}: {args.kind} design, K={mask.K}, feature {mask.feature_um} um")
    return 0


def run_import(args: argparse.Namespace) -> int:
    _plugin()
    import numpy as np

    from thintact_masks.design_io import design_record, write_json_atomic
    from thintact_masks.mask_import import import_pattern
    from thintact_sdk.interfaces import Mask

    out = claim_output(args.out, "file", force=args.force, inputs=(args.pattern,))
    phi, phi_rows = import_pattern(args.pattern, args.K, args.open_dark, args.feature_um, args.layer)
    mask = Mask(phi=phi, feature_um=float(args.feature_um), phi_rows=phi_rows, design="imported",
                provenance={"source": args.pattern.name})
    path = write_json_atomic(out, design_record(mask))
    shared = " (rows and columns share one sequence: see docs/calibration.md, pose ambiguities)" \
        if np.array_equal(phi, phi_rows) or np.array_equal(phi, phi_rows[::-1]) else ""
    print(f"{path}: imported design, K={mask.K}, feature {mask.feature_um} um{shared}")
    return 0


def _profile_source(name_or_path: str) -> Path | None:
    """The YAML file a profile argument names (a path, or a profile on the search path)."""
    from thintact_sdk.plugin_support import available_profiles

    p = Path(name_or_path)
    src = p if p.is_file() else available_profiles().get(str(name_or_path))
    return src if src is not None and src.suffix.lower() in (".yaml", ".yml") else None


def _write_keeping_text(name_or_path: str, new: Any, mask: dict[str, Any], out: Path) -> Path | None:
    """Write ``new`` as the source YAML with only its mask section replaced (comments and
    layout kept, phi in flow style); None when the source or ``out`` is not YAML or the
    edit does not give back ``new`` (the caller then writes the profile afresh)."""
    from thintact_masks.profile_text import replace_mask_section
    from thintact_sdk.plugin_support import profile_from_dict
    from thintact_sdk.plugin_support import safe_yaml as yaml_safe

    src = _profile_source(name_or_path)
    if src is None or Path(out).suffix.lower() == ".json":
        return None
    text = replace_mask_section(src.read_text(encoding="utf-8"), mask)
    if text is None:
        return None
    try:
        check = profile_from_dict(yaml_safe.load(text), where=str(out))
    except Exception:  # noqa: BLE001 - any failure: fall back to a fresh, validated write
        return None
    if check.contract_dict() != new.contract_dict():
        return None
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def run_apply(args: argparse.Namespace) -> int:
    _plugin()
    from thintact_masks.design_io import load_design
    from thintact_sdk.plugin_support import load_profile, profile_from_dict, write_profile

    out = claim_output(args.out, "file", force=args.force,
                       inputs=(args.design, file_input(args.profile)))
    mask, rec = load_design(args.design)
    profile = load_profile(args.profile)
    d = profile.contract_dict()
    d["mask"] = {**d["mask"], "phi": [int(v) for v in mask.phi], "design": mask.design,
                 "feature_um": mask.feature_um or profile.mask.feature_um}
    d["mask"].pop("phi_rows", None)
    if mask.phi_rows is not None:
        d["mask"]["phi_rows"] = [int(v) for v in mask.phi_rows]
    new = profile_from_dict(d, where=str(out))
    path = _write_keeping_text(args.profile, new, d["mask"], out) or write_profile(new, out)
    if rec.get("scale", 1.0) != 1.0:
        print(f"warning: {args.design} was optimised on a device scaled by {rec['scale']}")
    print(f"{path}: profile {new.name!r} with the {mask.design} mask (K={mask.K})")
    return 0
