"""``thintact real2sim train|evaluate``: the paper's Real2Sim (CycleGAN) for tactile images."""

from __future__ import annotations

import argparse
import json
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
    t.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    t.add_argument("--seed", type=seed, default=0)
    t.add_argument("--fresh", action="store_true",
                   help="ignore an existing checkpoint in --out (default: resume from it)")
    t.set_defaults(func=run_train)
    e = sp.add_parser("evaluate", help="the real-data table on presses the generator never saw")
    e.add_argument("--generator", type=Path, required=True, help="generator.pt from train")
    e.add_argument("--real", type=Path, required=True)
    e.add_argument("--json", type=Path, help="also write the table as JSON here")
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
    import numpy as np
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from thintact_sdk.tactile.calibration.gelsight_eval import split_presses
    from thintact_sdk.tactile.learning.domains import RealPresses, sensor_profile, simulated_presses
    from thintact_sdk.tactile.learning.train import Real2SimTrainer, TrainConfig

    if args.sim_presses < 1 or args.mm_per_px <= 0 or args.ball_radius_mm <= 0:
        raise ThinTactError("--sim-presses must be ≥ 1, --mm-per-px and --ball-radius-mm > 0")
    real = RealPresses.from_pack(args.real)
    train, test = split_presses(len(real.images), args.train)
    if not train or max(train) >= len(real.images) or min(train) < 0:
        raise ThinTactError(f"--train: press indices must lie in 0..{len(real.images) - 1}")
    rows, cols = real.reference.shape[:2]
    sim = simulated_presses(sensor_profile(rows, cols, args.mm_per_px), args.sim_presses,
                            args.ball_radius_mm, seed=args.seed)
    trainer = Real2SimTrainer(np.concatenate([real.subset(train), real.reference[None]]), sim,
                              args.out, TrainConfig(iterations=args.iterations, seed=args.seed),
                              args.device)
    if args.fresh:
        trainer.checkpoint_path.unlink(missing_ok=True)
    elif trainer.resume():
        print(f"resuming {trainer.checkpoint_path} at iteration {trainer.iteration}")
    meta = {"real_source": str(args.real), "train_presses": train, "test_presses": test,
            "real_shape": [rows, cols, 3],
            "mm_per_px": args.mm_per_px, "ball_radius_mm": args.ball_radius_mm,
            "sim_presses": args.sim_presses}
    with Progress(TextColumn("real2sim"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TextColumn("{task.fields[loss]}"), TimeRemainingColumn()) as bar:
        task = bar.add_task("train", total=args.iterations, completed=trainer.iteration, loss="")

        def on_step(i: int, losses: dict[str, float]) -> None:
            bar.update(task, completed=i,
                       loss=f"cycle {losses['cycle']:.3f} adv {losses['g_adv']:.3f}")

        result = trainer.run(on_step, meta)
    print(f"trained {result.iterations} iterations in {result.seconds:.0f} s on {result.device}; "
          f"generator {result.generator_path} (test presses kept unseen: {len(test)})")
    return 0


def run_evaluate(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from thintact_sdk.tactile.learning.evaluate import evaluate_real2sim
    from thintact_sdk.tactile.learning.translate import Real2SimTranslator

    translator = Real2SimTranslator.load(args.generator)
    rows, evals = evaluate_real2sim(args.real, translator)
    table = Table(title=f"held-out presses: {len(evals['real'].test)} "
                  f"(trained on {len(evals['real'].train)})")
    for col in ("method", "slope RMS (mm/mm)", "depth RMS (mm)"):
        table.add_column(col)
    for r in rows:
        table.add_row(r.method, f"{r.slope_rms:.3f}", f"{r.depth_rms_mm:.3f}")
    Console().print(table)
    if args.json is not None:
        args.json.write_text(json.dumps({
            "train": evals["real"].train, "test": evals["real"].test,
            "rows": [r.__dict__ for r in rows]}, indent=1) + "\n")
    return 0


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
