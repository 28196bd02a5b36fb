"""Where a GA run evaluates its fitness: in this process (numpy or torch CUDA) or on Ray."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from thintact_masks.errors import MaskDesignError
from thintact_masks.fitness import FitnessEvaluator
from thintact_masks.fitness_torch import DEVICE_CHOICES, TorchBatchFitness, resolve_device
from thintact_masks.ga import BatchFitnessFn


@dataclass
class Engine:
    """The fitness engine of one run.

    Attributes
    ----------
    batch_fitness
        What the GA calls with each generation's new genes; ``None`` for the local numpy
        path (``fitness_fn`` in threads, exactly as without an engine).
    device
        ``"cpu"`` (numpy arithmetic) or ``"cuda"`` (torch on a GPU).
    pool
        The :class:`~thintact_masks.ray_pool.RayFitnessPool` when evaluating on Ray.
    """

    batch_fitness: BatchFitnessFn | None
    device: str
    pool: Any = None

    def run_key(self) -> dict[str, Any]:
        """What the engine adds to the checkpoint's run key: a GPU's fitness may differ from
        the CPU's in its noise realisation (see :mod:`thintact_masks.fitness_torch`), so a run
        does not resume across the two; the CPU engines (local or Ray) add nothing."""
        return {"fitness_device": "cuda"} if self.device == "cuda" else {}


@contextmanager
def open_engine(evaluator: FitnessEvaluator, ray: str | None = None, workers: int | None = None,
                ray_batch: int | None = None, device: str = "auto") -> Iterator[Engine]:
    """The fitness engine for a run, closed (Ray shut down if started here) on exit.

    Parameters
    ----------
    evaluator
        The run's fitness evaluator.
    ray
        ``None``: evaluate in this process; ``"auto"``: a private local Ray cluster of
        ``workers`` CPUs (default: this machine's CPUs); else a Ray cluster address.
    workers
        Local path: threads evaluating at once (the GA's ``workers``); ``--ray auto``: CPUs of
        the local cluster; ignored with a cluster address.
    ray_batch
        Genes per Ray task (default: about two tasks per worker and generation).
    device
        ``"auto"`` (CUDA when torch sees one here, or when the Ray cluster has GPUs),
        ``"cpu"`` (numpy) or ``"cuda"``.
    """
    if device not in DEVICE_CHOICES:
        raise MaskDesignError(f"--device must be one of {', '.join(DEVICE_CHOICES)}, got {device!r}")
    if ray is None:
        resolved = resolve_device(device)
        if resolved == "cuda":
            yield Engine(TorchBatchFitness(evaluator, "cuda"), "cuda")
        else:
            yield Engine(None, "cpu")
        return
    from thintact_masks.ray_pool import AUTO_ADDRESS, RayFitnessPool

    num_cpus = (workers or os.cpu_count() or 1) if ray == AUTO_ADDRESS else None
    with RayFitnessPool(evaluator, ray, num_cpus, ray_batch, device=device) as pool:
        yield Engine(pool, pool.device, pool)
