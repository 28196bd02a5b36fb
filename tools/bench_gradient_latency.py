"""Time ``TactileInterpreter.interpret`` with each gradient model on a device's working grid.

The robot path's cost of a calibration that chose a network: the device's shipped table, then
the same table with a per-pixel network and with a convolutional network of the shipped
architecture (random weights: the cost does not depend on them), interpreting the vendored
GelSight presses against their no-contact frame. Rounds alternate the models so that load
changes fall on all of them; torch runs on ``--torch-threads`` (one: what a stream on a
two-core host uses). Prints the host first.

Usage::

    python tools/bench_gradient_latency.py [--rounds 4] [--frames 100] [--torch-threads 1] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import time
from importlib.resources import files

import numpy as np

from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.host.machine import machine_summary
from thintact_sdk.tactile.calibration.gelsight_eval import load_pack
from thintact_sdk.tactile.interpretation import gradient_model as gm
from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT


def _random_cnn(shape: tuple[int, int], rng: np.random.Generator) -> gm.ConvGradient:
    w: dict[str, np.ndarray] = {}
    cin = gm.INPUTS
    for k, _ in enumerate(gm.CNN_DILATIONS):
        w[f"w{k}"] = rng.normal(0, 0.2, (3, 3, cin, gm.CNN_WIDTH)).astype(np.float32)
        w[f"b{k}"] = np.zeros(gm.CNN_WIDTH, np.float32)
        cin = gm.CNN_WIDTH
    n = len(gm.CNN_DILATIONS)
    w[f"w{n}"] = rng.normal(0, 0.01, (cin, 2)).astype(np.float32)
    w[f"b{n}"] = np.zeros(2, np.float32)
    return gm.ConvGradient(w, gm.CNN_DILATIONS, shape)


def _random_mlp(shape: tuple[int, int], rng: np.random.Generator, hidden: int = 32) -> gm.MLPGradient:
    sizes = [(gm.INPUTS, hidden), (hidden, hidden), (hidden, 2)]
    w: dict[str, np.ndarray] = {}
    for k, (a, b) in enumerate(sizes):
        w[f"w{k}"] = rng.normal(0, 0.2, (a, b)).astype(np.float32)
        w[f"b{k}"] = np.zeros(b, np.float32)
    return gm.MLPGradient(w, shape)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", default="gelsight-mini")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--torch-threads", type=int, default=1)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    import torch

    torch.set_num_threads(args.torch_threads)
    profile = load_profile(args.profile)
    base = files("thintact_sdk") / "data" / "gelsight"
    lut = PhotometricLUT.load(base / "gelsight-mini-lut.npz")
    pack = load_pack(base / "gelsight_ball_presses.npz")
    imgs = pack["imgs"].astype(np.float32) / 255.0
    f0 = pack["f0"].astype(np.float32) / 255.0
    shape = (int(f0.shape[0]), int(f0.shape[1]))
    rng = np.random.default_rng(0)
    nets: dict[str, gm.MLPGradient | gm.ConvGradient | None] = {
        "table": None, "mlp": _random_mlp(shape, rng), "cnn": _random_cnn(shape, rng)}
    print(machine_summary(), f"| torch threads {torch.get_num_threads()} | grid {shape[0]}×{shape[1]}")
    res: dict[str, list[float]] = {k: [] for k in nets}
    for _ in range(args.rounds):
        for kind, net in nets.items():
            interp = TactileInterpreter(profile, PhotometricLUT(lut.lo, lut.hi, lut.table, lut.counts,
                                                                dict(lut.meta), net))
            interp.set_reference(f0)
            interp.interpret(imgs[0])  # warm
            ts = []
            for k in range(args.frames):
                t0 = time.perf_counter()
                interp.interpret(imgs[k % len(imgs)])
                ts.append(time.perf_counter() - t0)
            res[kind].append(float(np.median(ts)) * 1e3)
    for kind, vs in res.items():
        print(f"{kind:5s} interpret median per round: " + ", ".join(f"{v:.2f}" for v in vs) + " ms")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"host": machine_summary(), "grid": shape, "torch_threads": args.torch_threads,
                       "median_ms": res}, f, indent=1)


if __name__ == "__main__":
    main()
