"""Benchmark: one GA generation at the paper's scale, locally and on a local Ray cluster.

Measures, in one run on this host, the fitness evaluation of one generation of the paper's GA
(K = 770 genes, ``--population`` individuals, default 200, on the full-size ``thintact-paper``
device): the local path with 1 and 2 threads, and Ray with 1 and 2 workers (a private
2-CPU cluster on 127.0.0.1). From the Ray runs it derives the per-individual cost and the
per-task overhead, and from those it projects the wall time of the paper's whole run
(2000 generations) on N workers (``T(N) = ceil(P / (N·b)) · (b·c + o)`` per generation, with
``b = ceil(P / N)`` individuals per task), which stops improving once ``N ≥ P``.

Usage::

    .venv/bin/python tools/bench_mask_ray.py [--population 200] [--json out.json]

Nothing leaves loopback: the cluster is local, usage statistics are off.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

from thintact_masks.fitness import FitnessEvaluator  # noqa: E402
from thintact_masks.ga import evaluate_population  # noqa: E402
from thintact_masks.ray_pool import RayFitnessPool, connect  # noqa: E402

from thintact_sdk.formats.profiles import load_profile  # noqa: E402
from thintact_sdk.host.machine import machine_summary  # noqa: E402

PAPER_K = 770
PAPER_GENERATIONS = 2000
PROJECT_WORKERS = (8, 64, 256)


def _genes(population: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (2 * rng.integers(0, 2, (population, PAPER_K)) - 1).astype(np.int8)


def projected_generation_s(population: int, workers: int, per_individual_s: float,
                           per_task_s: float) -> float:
    """Generation time on ``workers`` workers, one task of ``ceil(P/N)`` individuals each."""
    batch = math.ceil(population / workers)
    rounds = math.ceil(population / (workers * batch))
    return rounds * (batch * per_individual_s + per_task_s)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--population", type=int, default=200, help="individuals (paper 200)")
    ap.add_argument("--json", type=Path, help="also write the figures to this file")
    args = ap.parse_args()
    genes = _genes(args.population)
    started = time.time()
    ev = FitnessEvaluator(load_profile("thintact-paper"), PAPER_K)
    out: dict[str, Any] = {"host": machine_summary(), "load_before": os.getloadavg(),
                           "population": args.population, "K": PAPER_K, "local_s": {}, "ray": {}}
    reference = None
    for threads in (1, 2):  # 1: one evaluation at a time (BLAS on both cores); 2: two, one BLAS thread each
        t0 = time.perf_counter()
        fit = evaluate_population(genes, ev.fitness, workers=threads)
        out["local_s"][threads] = time.perf_counter() - t0
        reference = fit if reference is None else reference
        print(f"local, {threads} thread(s): {out['local_s'][threads]:.1f} s", flush=True)
    connect("auto", num_cpus=2)
    for workers, cpus_per_task in ((1, 2.0), (2, 1.0)):
        batch = math.ceil(args.population / (2 * workers))  # about two tasks per worker
        with RayFitnessPool(ev, batch_size=batch, cpus_per_task=cpus_per_task, device="cpu") as pool:
            t0 = time.perf_counter()
            fit = pool(genes)
            wall = time.perf_counter() - t0
            stats = pool.history[-1]
        # equal up to BLAS summation order (threads per process differ between the paths)
        assert reference is not None and np.allclose(fit, reference, rtol=1e-9), "Ray fitness differs"
        per_individual = stats.compute_s / stats.genes
        overhead = max(wall * workers - stats.compute_s, 0.0) / stats.tasks
        out["ray"][workers] = {"wall_s": wall, "tasks": stats.tasks, "batch": batch,
                               "compute_s": stats.compute_s, "per_individual_s": per_individual,
                               "overhead_per_task_s": overhead}
        print(f"Ray, {workers} worker(s): {wall:.1f} s ({stats.tasks} tasks of {batch}; "
              f"{per_individual:.3f} s per individual, {overhead * 1e3:.0f} ms overhead per task)",
              flush=True)
    two = out["ray"][2]
    out["projection_h"] = {
        n: PAPER_GENERATIONS * projected_generation_s(args.population, n, two["per_individual_s"],
                                                      two["overhead_per_task_s"]) / 3600
        for n in (1, 2, *PROJECT_WORKERS)}
    out["load_after"] = os.getloadavg()
    out["wall_s"] = time.time() - started
    for n, hours in out["projection_h"].items():
        print(f"projected 2000 generations on {n:>3} workers: {hours:8.2f} h")
    print(f"host: {out['host']}; load before/after: {out['load_before'][0]:.2f}/{out['load_after'][0]:.2f}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
