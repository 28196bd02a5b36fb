"""The gradient models on real and simulated presses (issue 29 item 3; docs/tactile.md).

Three measurements, each optional:

* ``--pack PATH:RADIUS_MM:MM_PER_PX`` (repeatable) with ``--variants``: for each variant of the
  convolutional network (``WIDTH:DILATIONS:STEPS``, e.g. ``16:1,2,4,8:3000``) the pack is
  calibrated on its even presses with ``model="auto"`` (``evaluate_pack``), and the table
  prints each model's validation slope RMS (held-out training presses: what chooses the
  variant) and the test presses' figures (what it gives; not used to choose).
* ``--shapes PROFILE``: the table, the per-pixel and the convolutional network calibrated on
  24 simulated ball presses of a simulated profile (exact slopes), then measured on the
  paper's chamfered prism and 4 mm sphere at 0.25-1 mm (three random poses each): whether a
  network trained on balls invents ball shapes on another indenter.
* ``--latency``: numpy inference time of the default networks at 120 × 160 and 240 × 320.

Prints Markdown with the host. Taxim with four variants takes about 10 minutes on one core;
a 427 × 320 pack about 8 minutes per variant.

    python tools/measure_gradient_models.py --pack ../shared/data/taxim_gelsight_ball_small/dataPack_small.npz:2:0.1245 \\
        --variants 16:1,2,4,8:3000 32:1,2,4,8:3000 --shapes gelsight-mini --latency
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from thintact_sdk.host.machine import machine_summary  # noqa: E402


def _variant(text: str) -> dict[str, Any]:
    width, dil, steps = text.split(":")
    return {"width": int(width), "dilations": tuple(int(d) for d in dil.split(",")),
            "steps": int(steps)}


def packs(specs: list[str], variants: list[str], ball_model: str) -> None:
    from thintact_sdk.tactile.calibration.press_pack import evaluate_pack, load_press_pack

    print("| pack | variant | validation slope RMS: table / per-pixel / conv. | chosen | "
          "sphere / R (middle half) | contact ratio | depth RMS | slope RMS | edge vs interior "
          "| time |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for spec in specs:
        path, radius_s, mm_s = spec.rsplit(":", 2)
        radius, mm = float(radius_s), float(mm_s)
        pack = load_press_pack(path)
        for v in variants:
            t0 = time.perf_counter()
            res = evaluate_pack(pack, radius, mm, model="auto", ball_model=ball_model,
                                cnn_options=_variant(v))
            s, val = res["summary"], res["validation"] or {}
            edge = s.get("edge_radius_vs_interior_median")
            print(f"| {Path(path).name} | {v} | {val.get('slope_rms_lut', float('nan')):.3f} / "
                  f"{val.get('slope_rms_mlp', float('nan')):.3f} / "
                  f"{val.get('slope_rms_cnn', float('nan')):.3f} | {res['gradient_model']} | "
                  f"{s['sphere_radius_median_mm'] / radius:.3f} "
                  f"({s['sphere_radius_q25_mm'] / radius:.2f}-{s['sphere_radius_q75_mm'] / radius:.2f}) | "
                  f"{s['contact_ratio_median']:.3f} | {s['depth_rms_mm']:.3f} mm | "
                  f"{s['slope_rms']:.3f} | {'none' if edge is None else f'{edge:+.1%}'} | "
                  f"{time.perf_counter() - t0:.0f} s |", flush=True)


def shapes(profile_name: str, presses: int = 24, seed: int = 5) -> None:
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.calibration import ball_press as bp
    from thintact_sdk.tactile.calibration.evaluation import (
        PAPER_DEPTHS_MM,
        PAPER_INDENTERS,
        depth_rms,
    )
    from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
    from thintact_sdk.tactile.simulation.membrane import TactileSimulator

    profile = load_profile(profile_name)
    sim = TactileSimulator.for_profile(profile)
    p = sim.params
    ref = sim.flat().scene
    items = [bp.BallPress(s.scene, s.grad_x, s.grad_y)
             for s, _ in bp.random_ball_presses(profile, presses, seed=0)]
    rng = np.random.default_rng(seed)
    hx, hy = p.cols / 2 * p.mm_per_px - 3.0, p.rows / 2 * p.mm_per_px - 3.0
    tests = [(name, sim.press(ind, d, (rng.uniform(-hx, hx), rng.uniform(-hy, hy)),
                              rng.uniform(0, 180)))
             for name, ind in PAPER_INDENTERS.items() for d in PAPER_DEPTHS_MM for _ in range(3)]
    print(f"\n{profile_name}: calibrated on {presses} simulated ball presses, depth RMS (mm, "
          f"paper's area) on {len(tests)} presses of other poses")
    print("| model | " + " | ".join(PAPER_INDENTERS) + " | calibration |")
    print("|---|" + "---|" * (len(PAPER_INDENTERS) + 1))
    for model in ("lut", "mlp", "cnn"):
        t0 = time.perf_counter()
        lut = bp.calibrate_from_presses(profile, ref, items, model=model)
        took = time.perf_counter() - t0
        interp = TactileInterpreter(profile, lut)
        interp.set_reference(ref)
        err: dict[str, list[float]] = {}
        for name, truth in tests:
            err.setdefault(name, []).append(depth_rms(
                interp.depth_from_image(truth.scene), truth.depth_mm, p.contact_threshold_mm))
        print(f"| {model} | " + " | ".join(f"{np.mean(err[n]):.4f}" for n in PAPER_INDENTERS)
              + f" | {took:.0f} s |", flush=True)


def latency(repeats: int = 20) -> None:
    from thintact_sdk.tactile.interpretation.gradient_model import (
        CNN_DILATIONS,
        CNN_WIDTH,
        INPUTS,
        ConvGradient,
        MLPGradient,
    )

    rng = np.random.default_rng(0)

    def w(*shape: int) -> np.ndarray:
        return rng.normal(0, 0.1, shape).astype(np.float32)

    print("\n| grid | per-pixel network | convolutional network |\n|---|---|---|")
    for shape in ((120, 160), (240, 320)):
        mlp = MLPGradient({"w0": w(INPUTS, 32), "b0": w(32), "w1": w(32, 32), "b1": w(32),
                           "w2": w(32, 2), "b2": w(2)}, shape)
        cw: dict[str, np.ndarray] = {}
        cin = INPUTS
        for k in range(len(CNN_DILATIONS)):
            cw[f"w{k}"], cw[f"b{k}"] = w(3, 3, cin, CNN_WIDTH), w(CNN_WIDTH)
            cin = CNN_WIDTH
        n = len(CNN_DILATIONS)
        cw[f"w{n}"], cw[f"b{n}"] = w(cin, 2), w(2)
        cnn = ConvGradient(cw, CNN_DILATIONS, shape)
        change = w(*shape, 3)
        image = 0.5 + change
        times = []
        for net in (mlp, cnn):
            net.predict(change, image)
            t0 = time.perf_counter()
            for _ in range(repeats):
                net.predict(change, image)
            times.append((time.perf_counter() - t0) / repeats * 1e3)
        print(f"| {shape[0]} × {shape[1]} | {times[0]:.1f} ms | {times[1]:.1f} ms |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pack", action="append", default=[], help="PATH:RADIUS_MM:MM_PER_PX")
    ap.add_argument("--variants", nargs="+", default=["16:1,2,4,8:3000"],
                    help="WIDTH:DILATIONS:STEPS of the convolutional network")
    ap.add_argument("--ball-model", default="auto", choices=("auto", "rigid", "sink-in"))
    ap.add_argument("--shapes", metavar="PROFILE", help="simulated profile for the shape check")
    ap.add_argument("--latency", action="store_true")
    args = ap.parse_args()
    print(f"host: {machine_summary()}\n")
    if args.pack:
        packs(args.pack, args.variants, args.ball_model)
    if args.shapes:
        shapes(args.shapes)
    if args.latency:
        latency()


if __name__ == "__main__":
    main()
