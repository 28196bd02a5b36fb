"""``thintact real2sim train|evaluate``: the paper's Real2Sim (CycleGAN) for tactile images."""

from __future__ import annotations

import argparse
from pathlib import Path

from thintact_sdk.apps.cli.argtypes import (
    float_range,
    int_range,
    positive_float,
    positive_int,
    seed,
)
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import MAX_PITCH_UM, MIN_PITCH_UM
from thintact_sdk.formats.safe_yaml import dump_json


def _indices(text: str) -> list[int] | None:
    if text == "even":
        return None
    try:
        return [int(t) for t in text.split(",") if t.strip()]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"'even' or comma-separated press indices: {text!r}") from exc


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("real2sim", help="train / evaluate Real2Sim (real → simulation-like images)",
                       description="Real2Sim (paper §VI-C): a CycleGAN that turns real tactile "
                       "images into simulation-like ones before photometric stereo.")
    sp = p.add_subparsers(dest="real2sim_command", metavar="ACTION", required=True)
    t = sp.add_parser("train", help="train on real presses and the SDK's simulation of them")
    t.add_argument("--real", type=Path, required=True,
                   help="real presses: .npz with imgs (P×H×W×3) and f0 (no-contact)")
    t.add_argument("--out", type=Path, required=True, help="run directory (checkpoints, generator)")
    t.add_argument("--train", type=_indices, default=None, metavar="even|I,J,…",
                   help="presses to train on (default: the even ones); the rest stay unseen")
    t.add_argument("--iterations", type=positive_int, default=3000)
    t.add_argument("--sim-presses", type=positive_int, default=48, help="simulated presses (sim domain)")
    t.add_argument("--mm-per-px", type=float_range(MIN_PITCH_UM / 1000, MAX_PITCH_UM / 1000), default=0.1245,
                   help="real image pixel size, mm (a tactile pixel: 0.0001 to 10)")
    t.add_argument("--ball-radius-mm", type=positive_float, default=2.0)
    t.add_argument("--sim-model", type=Path, default=None, metavar="FITTED.yaml",
                   help="the sim domain: the simulation `thintact diagnose-tactile` fitted to this "
                   "sensor (its fitted_tactile.yaml); default the SDK's nominal tactile simulation")
    t.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    t.add_argument("--seed", type=seed, default=0)
    t.add_argument("--fresh", action="store_true",
                   help="ignore an existing checkpoint in --out (default: resume from it)")
    t.add_argument("--quiet", action="store_true", help="no progress lines")
    t.set_defaults(func=run_train)
    e = sp.add_parser("evaluate", help="the real-data table on presses the generator never saw")
    e.add_argument("--generator", type=Path, required=True, help="generator.pt from train")
    e.add_argument("--real", type=Path, required=True)
    e.add_argument("--json", type=Path, help="also write the tables as JSON here")
    e.add_argument("--skip-ball-figures", action="store_true",
                   help="only the annotated-circle table (the annotation-free ball figures "
                   "calibrate every row from its training presses: minutes)")
    e.add_argument("--quiet", action="store_true", help="no progress lines")
    e.set_defaults(func=run_evaluate)
    b = sp.add_parser("bench", help="translation time per frame at a profile's working grid")
    b.add_argument("--generator", type=Path, required=True)
    b.add_argument("--profile", default="thintact-paper",
                   help="device whose tactile working grid sets the frame size")
    b.add_argument("--frames", type=int_range(3), default=50, help="frames timed (>= 3)")
    b.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    b.add_argument("--threads", type=positive_int, default=None,
                   help="torch CPU threads (default: torch's own choice)")
    b.set_defaults(func=run_bench)


def run_train(args: argparse.Namespace) -> int:
    from thintact_sdk.host.progress import stage_reporter
    from thintact_sdk.tactile.learning.train import train_from_pack

    if args.sim_presses < 1 or args.mm_per_px <= 0 or args.ball_radius_mm <= 0:
        raise ThinTactError("--sim-presses must be ≥ 1, --mm-per-px and --ball-radius-mm > 0")
    with stage_reporter(args.quiet) as say:

        def on_step(i: int, total: int, losses: dict[str, float], seconds: float) -> None:
            if i % 50 == 0 or i == total:  # a line per 50 iterations off a terminal
                left = seconds / max(i, 1) * (total - i)
                say(f"iteration {i}/{total}: cycle {losses['cycle']:.3f}, adversarial "
                    f"{losses['g_adv']:.3f}; about {left / 60:.0f} min left")

        result, resumed_at, test = train_from_pack(
            args.real, args.out, args.train, args.iterations, args.sim_presses, args.mm_per_px,
            args.ball_radius_mm, args.sim_model, args.device, args.seed, args.fresh, on_step)
    if resumed_at:
        print(f"resumed {args.out / 'checkpoint.pt'} at iteration {resumed_at}")
    print(f"trained {result.iterations} iterations in {result.seconds:.0f} s on {result.device}; "
          f"generator {result.generator_path} (test presses kept unseen: {len(test)})")
    return 0


def run_evaluate(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from thintact_sdk.host.progress import stage_reporter
    from thintact_sdk.tactile.learning.evaluate import ball_figures, evaluate_real2sim
    from thintact_sdk.tactile.learning.translate import Real2SimTranslator

    translator = Real2SimTranslator.load(args.generator)
    with stage_reporter(args.quiet) as say:
        say("annotated-circle figures")
        rows, evals = evaluate_real2sim(args.real, translator)
        balls = {} if args.skip_ball_figures else ball_figures(args.real, translator, stage=say)
    table = Table(title=f"held-out presses: {len(evals['real'].test)} "
                  f"(trained on {len(evals['real'].train)}), inside the annotated circles")
    for col in ("method", "slope RMS (mm/mm)", "depth RMS (mm)"):
        table.add_column(col)
    for r in rows:
        table.add_row(r.method, f"{r.slope_rms:.3f}", f"{r.depth_rms_mm:.3f}")
    Console().print(table)
    if balls:
        Console().print(_ball_table(balls))
    if args.json is not None:
        args.json.write_text(dump_json({
            "train": evals["real"].train, "test": evals["real"].test,
            "rows": [r.__dict__ for r in rows], "ball_figures": balls}) + "\n")
    return 0


def _ball_table(balls: dict) -> object:
    from rich.table import Table

    t = Table(title="annotation-free figures (issue 29 items 1-2), against the fixed-radius ball")
    for col in ("method", "gradient model", "sphere radius median (middle half)",
                "contact / sqrt(2Rp-p^2)", "depth RMS (mm)", "slope RMS (flat)"):
        t.add_column(col)
    for name, res in balls.items():
        s = res["summary"]
        ratio = s["contact_ratio_median"]
        t.add_row(name, str(res["gradient_model"] or "lut"),
                  f"{s['sphere_radius_median_mm']:.2f} mm ({s['sphere_radius_q25_mm']:.2f}-"
                  f"{s['sphere_radius_q75_mm']:.2f})",
                  "-" if ratio is None else f"{ratio:.2f}", f"{s['depth_rms_mm']:.3f}",
                  f"{s['slope_rms']:.3f} ({s['slope_rms_flat']:.2f})")
    return t


def run_bench(args: argparse.Namespace) -> int:
    import os
    import time

    import numpy as np
    import torch

    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.host.machine import machine_summary
    from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
    from thintact_sdk.tactile.learning.translate import Real2SimTranslator

    if args.frames < 3 or (args.threads is not None and args.threads < 1):
        raise ThinTactError("--frames must be ≥ 3 and --threads ≥ 1")
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    translator = Real2SimTranslator.load(args.generator, args.device)
    work = TactileInterpreter(load_profile(args.profile)).work
    shapes: list[tuple[int, ...]] = [(work.rows, work.cols, 3)]
    trained = translator.meta.get("real_shape")
    if trained and tuple(trained) != shapes[0]:
        shapes.append(tuple(int(v) for v in trained))
    print(machine_summary())
    print(f"load average {os.getloadavg()[0]:.1f}; device {translator.device}")
    rng = np.random.default_rng(0)
    for shape in shapes:
        image = rng.random(shape, dtype=np.float32)
        translator(image)  # warm-up
        times = []
        for _ in range(args.frames):
            t0 = time.perf_counter()
            translator(image)
            times.append((time.perf_counter() - t0) * 1e3)
        label = f"{args.profile} working grid" if shape == shapes[0] else "training images"
        print(f"{shape[0]}×{shape[1]} ({label}): median {np.median(times):.2f} ms, "
              f"p95 {np.percentile(times, 95):.2f} ms per frame over {args.frames} frames")
    return 0
