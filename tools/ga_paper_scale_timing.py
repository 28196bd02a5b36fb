#!/usr/bin/env python
"""Time the mask GA at the paper's scale: K = 770, 200 individuals, full-size system
matrices (Pc 1024×400, Qc 1280×512), over the initial population and 1-2 generations.

Usage::

    .venv/bin/python tools/ga_paper_scale_timing.py [--generations 1] [--workers 1] [--float32]

Prints the machine summary, the seconds per generation (and per fitness evaluation) and the
extrapolated time of the paper's 2000 generations. On a shared machine the figure is an
upper bound of what the code needs: report it with the load average printed alongside.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import thintact_sdk  # noqa: F401 - sets the OpenBLAS core type before numpy loads


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default="thintact-paper")
    ap.add_argument("--K", type=int, default=770)
    ap.add_argument("--population", type=int, default=200)
    ap.add_argument("--generations", type=int, default=1, choices=(1, 2))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--float32", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    import numpy as np
    from thintact_masks.fitness import FitnessEvaluator, FitnessSettings
    from thintact_masks.ga import GAConfig, GAState, run_ga

    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.host.blas import blas_threads
    from thintact_sdk.host.machine import machine_summary

    print(f"machine: {machine_summary()}")
    print(f"load average before: {os.getloadavg()}")
    profile = load_profile(args.profile)
    settings = FitnessSettings(dtype="float32" if args.float32 else "float64")
    t0 = time.perf_counter()
    evaluator = FitnessEvaluator(profile, args.K, settings)
    setup_s = time.perf_counter() - t0
    print(f"device {profile.name}: Pc {profile.sensor.rows}x{profile.scene.rows}, "
          f"Qc {profile.sensor.cols}x{profile.scene.cols}, K={args.K}, "
          f"population {args.population}, {settings.dtype}, workers {args.workers}, "
          f"setup {setup_s:.2f} s")
    calls = {"n": 0}

    def fitness(phi: np.ndarray) -> float:
        calls["n"] += 1
        return evaluator.fitness(phi)

    marks: list[tuple[int, float, int]] = []
    start = time.perf_counter()

    def progress(state: GAState) -> None:
        marks.append((state.generation, time.perf_counter(), calls["n"]))
        print(f"  generation {state.generation}: best {state.best_fitness:.4f}, "
              f"{time.perf_counter() - start:.1f} s elapsed, {calls['n']} evaluations", flush=True)

    config = GAConfig(population=args.population, generations=args.generations, seed=args.seed)
    with blas_threads(1):
        run_ga(args.K, config, fitness, None, None, progress, args.workers)
    init_s = marks[0][1] - start
    print(f"initial population: {init_s:.1f} s for {marks[0][2]} evaluations "
          f"({init_s / marks[0][2]:.3f} s each)")
    per_gen = []
    for (_, t_prev, n_prev), (g, t, n) in zip(marks, marks[1:], strict=False):
        dt = t - t_prev
        per_gen.append(dt)
        print(f"generation {g}: {dt:.1f} s for {n - n_prev} new evaluations "
              f"({dt / max(n - n_prev, 1):.3f} s each)")
    mean_gen = sum(per_gen) / len(per_gen)
    print(f"RESULT: {mean_gen:.1f} s per generation at paper scale -> 2000 generations "
          f"~ {mean_gen * 2000 / 3600:.1f} h (load average after: {os.getloadavg()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
