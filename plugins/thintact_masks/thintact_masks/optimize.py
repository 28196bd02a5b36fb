"""A complete mask optimisation: GA on a device, baselines, design file and fitness plot."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from thintact_masks.design_io import design_record, plot_fitness, write_json_atomic
from thintact_masks.devices import scaled_profile
from thintact_masks.engines import open_engine
from thintact_masks.fitness import FitnessEvaluator, FitnessSettings
from thintact_masks.ga import GAConfig, ProgressFn, run_ga
from thintact_masks.mls import MLSDesigner, random_phi
from thintact_sdk.errors import InvalidValueError
from thintact_sdk.interfaces import Mask
from thintact_sdk.plugin_support import Profile, blas_threads

DESIGN_NAME = "design.json"
PLOT_NAME = "fitness.png"


def optimize_mask(profile: Profile, config: GAConfig, K: int | None = None,  # noqa: N803
                  settings: FitnessSettings | None = None, scale: float = 1.0,
                  out_dir: str | os.PathLike[str] | None = None,
                  progress: ProgressFn | None = None, workers: int | None = None,
                  ray: str | None = None, ray_batch: int | None = None,
                  fitness_device: str = "auto"
                  ) -> tuple[Mask, dict[str, Any]]:
    """Optimise φ for ``profile`` with the paper's GA; resumable through ``out_dir``.

    Parameters
    ----------
    profile
        The device.
    config
        GA settings.
    K
        Mask length (default: the profile's, times ``scale``).
    settings
        Fitness settings.
    scale
        Run on :func:`thintact_masks.devices.scaled_profile` of the device (0 < scale ≤ 1).
    out_dir
        Where ``checkpoint.npz``, ``design.json`` and ``fitness.png`` go; an existing
        checkpoint of the same run is continued.
    progress
        Called with the GA state after every generation.
    workers
        Individuals evaluated concurrently, each with single-threaded BLAS (default 1; the
        result does not depend on it); with ``ray="auto"`` the CPUs of the local Ray cluster
        (default: this machine's).
    ray
        Evaluate each generation's individuals as Ray tasks: ``"auto"`` (a private local
        cluster) or a cluster address (:mod:`thintact_masks.ray_pool`); ``None`` evaluates here.
        The result does not depend on it.
    ray_batch
        Individuals per Ray task (default: about two tasks per worker and generation).
    fitness_device
        ``"auto"`` (torch CUDA when a GPU is there, else numpy), ``"cpu"`` or ``"cuda"``
        (:mod:`thintact_masks.engines`).

    Returns
    -------
    mask, record
        The best mask and its design record (also written to ``out_dir/design.json``).
    """
    device = scaled_profile(profile, scale)
    k = int(device.mask.K if K is None else (K if scale == 1.0 else max(2, round(K * scale))))
    settings = settings or FitnessSettings()
    evaluator = FitnessEvaluator(device, k, settings)
    run_key = {"profile_hash": profile.content_hash(), "scale": scale,
               "fitness": settings.to_dict()}
    with (blas_threads(1),
          open_engine(evaluator, ray, workers, ray_batch, fitness_device) as engine):
        state = run_ga(k, config, evaluator.fitness, out_dir, {**run_key, **engine.run_key()},
                       progress, workers or 1, engine.batch_fitness)
        best = state.best_phi
        best_eval = evaluator.evaluate(best)
        baselines = {
            "mls": evaluator.evaluate(MLSDesigner().design(k, device.mask.feature_um).phi),
            "random": evaluator.evaluate(random_phi(k, config.seed + 1)),
        }
    mask = Mask(phi=best, feature_um=device.mask.feature_um, design="ga",
                provenance={"seed": config.seed, "generations": state.generation,
                            "population": config.population, "fitness": best_eval.fitness,
                            "elapsed_s": round(state.elapsed_s, 3)})
    record = design_record(
        mask,
        profile=profile.name,
        profile_hash=profile.content_hash(),
        scale=scale,
        device={"sensor": [device.sensor.rows, device.sensor.cols, device.sensor.pixel_pitch_um],
                "scene": [device.scene.rows, device.scene.cols, device.scene.pixel_pitch_um],
                "geometry_mm": [device.geometry.scene_to_mask_mm,
                                device.geometry.mask_to_sensor_mm]},
        fitness=best_eval.fitness,
        fitness_parts=best_eval.parts,
        baselines={name: {"fitness": e.fitness, "parts": e.parts} for name, e in baselines.items()},
        improvement={name: best_eval.fitness - e.fitness for name, e in baselines.items()},
        history={"best": state.best_history, "mean": state.mean_history},
        settings={"ga": config.__dict__, "fitness": evaluator.describe(), "K": k},
    )
    if out_dir is not None:
        out = Path(out_dir)
        write_json_atomic(out / DESIGN_NAME, record)
        plot_fitness(state.best_history, state.mean_history, out / PLOT_NAME,
                     {name: e.fitness for name, e in baselines.items()},
                     title=f"GA on {device.name}: K={k}, population {config.population}")
    return mask, record


def baseline_phi(name: str, K: int, seed: int = 0) -> np.ndarray:  # noqa: N803
    """φ of a named baseline (``mls`` or ``random``) of length K."""
    if name == "mls":
        return MLSDesigner().design(K, 1.0).phi
    if name == "random":
        return random_phi(K, seed)
    raise InvalidValueError(f"unknown baseline {name!r}; use 'mls' or 'random'")
