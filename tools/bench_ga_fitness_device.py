#!/usr/bin/env python
"""Time one GA fitness batch on a torch device against the numpy (CPU) path, in the same run.

The mask GA scores each generation's population with ``FitnessEvaluator.fitness`` (numpy, one
gene at a time) or, with ``--device cuda``, with ``TorchBatchFitness`` (batched Gram
eigen-decompositions and image metrics on the GPU). This tool builds the evaluator at the
profile's size, draws ``--population`` random ±1 genes, and reports as JSON:

- ``cpu_s_per_gene``: numpy seconds per gene over ``--cpu-genes`` genes (the baseline);
- ``device_s_per_batch`` / ``device_s_per_gene``: torch seconds for the whole population after
  one warm-up batch (synchronised), ``speedup`` the ratio of the two per-gene figures;
- ``max_abs_fitness_diff``: the largest |fitness(torch) - fitness(numpy)| over the genes both
  scored (the two paths must agree).

Usage::

    python tools/bench_ga_fitness_device.py [--profile thintact-paper] [--K 770]
        [--population 64] [--cpu-genes 4] [--device cuda] [--float32]

``--device cpu`` runs the torch path on the CPU (for a try on a machine without a GPU).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import thintact_sdk  # noqa: F401 - sets the OpenBLAS core type before numpy loads


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default="thintact-paper")
    ap.add_argument("--K", type=int, default=None, help="mask length (default the profile's)")
    ap.add_argument("--population", type=int, default=64)
    ap.add_argument("--cpu-genes", type=int, default=4)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--max-batch", type=int, default=16)
    ap.add_argument("--float32", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.population < 1 or args.cpu_genes < 1 or args.cpu_genes > args.population:
        ap.error("need 1 <= --cpu-genes <= --population")

    import numpy as np
    import torch
    from thintact_masks.fitness import FitnessEvaluator, FitnessSettings
    from thintact_masks.fitness_torch import TorchBatchFitness

    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.host.machine import machine_summary

    profile = load_profile(args.profile)
    settings = FitnessSettings(dtype="float32" if args.float32 else "float64")
    t0 = time.perf_counter()
    evaluator = FitnessEvaluator(profile, args.K, settings)
    setup_s = time.perf_counter() - t0
    rng = np.random.default_rng(args.seed)
    genes = rng.choice(np.array([-1.0, 1.0]), size=(args.population, evaluator.K))

    t0 = time.perf_counter()
    cpu = np.array([evaluator.fitness(g) for g in genes[:args.cpu_genes]])
    cpu_s = (time.perf_counter() - t0) / args.cpu_genes

    def sync() -> None:
        if args.device.startswith("cuda"):
            torch.cuda.synchronize()

    batch = TorchBatchFitness(evaluator, args.device, max_batch=args.max_batch)
    batch(genes[:min(args.max_batch, args.population)])  # warm-up (kernels, workspaces)
    sync()
    t0 = time.perf_counter()
    dev = batch(genes)
    sync()
    dev_s = time.perf_counter() - t0
    diff = float(np.max(np.abs(dev[:args.cpu_genes] - cpu)))
    out = {
        "machine": machine_summary(),
        "device": (torch.cuda.get_device_name(0) if args.device.startswith("cuda")
                   else "cpu (torch)"),
        "torch": torch.__version__,
        "profile": profile.name,
        "K": evaluator.K,
        "scene": [profile.scene.rows, profile.scene.cols],
        "dtype": settings.dtype,
        "population": args.population,
        "max_batch": args.max_batch,
        "setup_s": round(setup_s, 3),
        "cpu_genes": args.cpu_genes,
        "cpu_s_per_gene": round(cpu_s, 4),
        "device_s_per_batch": round(dev_s, 4),
        "device_s_per_gene": round(dev_s / args.population, 5),
        "speedup": round(cpu_s / (dev_s / args.population), 2),
        "max_abs_fitness_diff": diff,
        "load_average": os.getloadavg(),
        "omp_threads": torch.get_num_threads(),
    }
    json.dump(out, sys.stdout, indent=1)
    print()
    return 0 if np.isfinite(dev).all() else 1


if __name__ == "__main__":
    raise SystemExit(main())
