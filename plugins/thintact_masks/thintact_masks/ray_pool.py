"""Fitness evaluation of a GA generation as Ray tasks (``thintact mask optimize --ray``).

The GA itself (selection, crossover, mutation, its random generator and the checkpoints)
stays in the driver; only the evaluation of each generation's new genes is distributed. The
fitness evaluator (the device's direct-generation operators, the scenes, the fixed noise
draws and the SSIM references: about 70 MB at paper scale) is put into Ray's object store
once per run; every task receives its reference (never the evaluator itself) and each worker
process deserialises it once and keeps it for the following tasks. A task evaluates a batch
of genes, so the per-task overhead is paid once per batch.

Faults: a task whose worker process or node dies is re-executed by Ray (``max_retries``), so
a killed worker costs the re-run of its batch; a failure that remains after the retries is
a :class:`~thintact_masks.errors.MaskDesignError`, and the run continues from its last
checkpoint when the same command is run again (on this or another cluster).

Ray is optional (``pip install -e '.[ray]'``): it is imported only here and only when a pool
is created, so the rest of the plugin works without it.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_masks.errors import MaskDesignError

#: ``--ray auto``: start a private local cluster (loopback only) for this run
AUTO_ADDRESS = "auto"
#: object store of a private local cluster: the evaluator (~70 MB at paper scale) and the
#: generation's genes and results fit many times over; Ray's default would reserve 30 % of RAM
LOCAL_OBJECT_STORE_BYTES = 512 * 2**20
#: set in the driver before Ray starts (a local cluster's processes inherit it): no usage
#: statistics are collected or sent
_RAY_ENV = {"RAY_USAGE_STATS_ENABLED": "0"}
#: Ray's switch between a multi-node address and loopback for a node (read by Ray at import
#: into ``ray._private.ray_constants.ENABLE_RAY_CLUSTER``; false on Windows and macOS)
_LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"

def import_ray() -> Any:
    """The ``ray`` module, or a :class:`MaskDesignError` saying how to install it."""
    for key, value in _RAY_ENV.items():
        os.environ.setdefault(key, value)
    try:
        import ray
    except ImportError:
        raise MaskDesignError(
            "--ray needs Ray, an optional extra of the SDK: pip install -e '.[ray]' "
            "(tools/bootstrap.sh installs it)") from None
    return ray


def connect(address: str = AUTO_ADDRESS, num_cpus: int | None = None) -> bool:
    """Start or join the Ray cluster of this process.

    Parameters
    ----------
    address
        ``"auto"`` starts a private local cluster of ``num_cpus`` CPUs (no dashboard, nodes
        bound to 127.0.0.1); anything else is the address of a running cluster
        (``HOST:6379`` GCS address or ``ray://HOST:10001`` client address).
    num_cpus
        CPUs of the local cluster (worker processes evaluating at once); only with ``"auto"``.

    A local cluster's servers listen on 127.0.0.1 only; usage statistics are off.

    Returns
    -------
    bool
        True when this call started Ray in this process (the caller shuts it down), False
        when Ray was already initialised here.
    """
    ray = import_ray()
    if ray.is_initialized():
        return False
    common: dict[str, Any] = {"log_to_driver": False, "logging_level": "ERROR",
                              "configure_logging": True}
    try:
        if address == AUTO_ADDRESS:
            if num_cpus is not None and num_cpus < 1:
                raise MaskDesignError(f"a local Ray cluster needs >= 1 CPU, got {num_cpus}")
            with _loopback_node():
                ray.init(address="local", num_cpus=num_cpus, include_dashboard=False,
                         object_store_memory=LOCAL_OBJECT_STORE_BYTES, **common)
        elif _is_loopback(address):  # a local cluster started by another driver
            with _loopback_node():
                ray.init(address=address, **common)
        else:
            ray.init(address=address, **common)
    except MaskDesignError:
        raise
    except Exception as err:  # Ray raises ConnectionError, RuntimeError, ValueError, ...
        raise MaskDesignError(f"cannot start or join the Ray cluster at {address!r}: "
                              f"{type(err).__name__}: {err}") from None
    return True


def _is_loopback(address: str) -> bool:
    """Whether a cluster address (``HOST:PORT`` or ``ray://HOST:PORT``) names this machine's
    loopback interface."""
    host = address.split("://", 1)[-1].rsplit(":", 1)[0].strip("[]")
    return host in ("127.0.0.1", "localhost", "::1")


@contextmanager
def _loopback_node() -> Iterator[None]:
    """Make a local cluster started in the block use 127.0.0.1 as its node address.

    On Linux Ray gives a node the host's network address, so its servers listen there; the
    switch it uses for single-machine platforms is set for the driver (the module constant,
    fixed when Ray was imported) and for the cluster's processes (the environment they
    inherit), then restored.
    """
    from ray._private import ray_constants

    saved_env = os.environ.get(_LOOPBACK_ENV)
    saved_flag = ray_constants.ENABLE_RAY_CLUSTER
    os.environ[_LOOPBACK_ENV] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = saved_flag
        if saved_env is None:
            os.environ.pop(_LOOPBACK_ENV, None)
        else:
            os.environ[_LOOPBACK_ENV] = saved_env


# -- worker side -----------------------------------------------------------------------------
#: the evaluator of the current run in this worker process: (object id, evaluator)
_worker_evaluator: tuple[str, Any] | None = None


def _evaluator_of(ref: Any) -> Any:
    """The evaluator behind ``ref``, fetched from the object store once per worker process."""
    global _worker_evaluator
    key = ref.hex()
    if _worker_evaluator is None or _worker_evaluator[0] != key:
        import ray

        _worker_evaluator = (key, ray.get(ref))
    return _worker_evaluator[1]


def evaluate_genes(boxed_ref: list[Any], genes: np.ndarray, device: str
                   ) -> tuple[np.ndarray, int, float]:
    """Ray task: fitness of a ``G × K`` batch of genes.

    ``boxed_ref`` is ``[ObjectRef of the FitnessEvaluator]`` (boxed, so that Ray passes the
    reference rather than a per-task copy). Returns the ``(G,)`` fitness, the worker's pid
    and the seconds spent evaluating.
    """
    from thintact_sdk.plugin_support import blas_threads

    evaluator = _evaluator_of(boxed_ref[0])
    t0 = time.perf_counter()
    with blas_threads(1):
        if device == "cpu":
            values = np.array([evaluator.fitness(g) for g in genes], np.float64)
        else:
            from thintact_masks.fitness_torch import TorchBatchFitness

            values = TorchBatchFitness(evaluator, device)(genes)
    return values, os.getpid(), time.perf_counter() - t0


# -- driver side -----------------------------------------------------------------------------
@dataclass
class GenerationStats:
    """What one :meth:`RayFitnessPool.__call__` did.

    Attributes
    ----------
    genes, tasks
        Genes evaluated and tasks submitted.
    wall_s
        Driver wall time from submission to the last result, s.
    compute_s
        Sum over tasks of the time spent evaluating inside the workers, s.
    worker_pids
        Distinct worker processes that returned results.
    """

    genes: int = 0
    tasks: int = 0
    wall_s: float = 0.0
    compute_s: float = 0.0
    worker_pids: set[int] = field(default_factory=set)


class RayFitnessPool:
    """Evaluates batches of genes as Ray tasks (a ``batch_fitness`` for :func:`~thintact_masks.ga.run_ga`).

    Parameters
    ----------
    evaluator
        The :class:`~thintact_masks.fitness.FitnessEvaluator` of the run; put into the object
        store once, here.
    address
        ``"auto"`` (private local cluster) or a cluster address; see :func:`connect`. Ignored
        when Ray is already initialised in this process.
    num_cpus
        CPUs of the local cluster with ``"auto"`` (default: all of this machine's).
    batch_size
        Genes per task; default ``ceil(G / (2 · cluster CPUs / cpus_per_task))`` so that
        each worker gets about two tasks per generation (load balance vs per-task overhead).
    cpus_per_task
        Ray CPUs a task holds (1: one single-threaded evaluation per CPU).
    max_retries
        Re-executions of a task whose worker or node died.
    device
        ``"cpu"`` (numpy, the local path's arithmetic), ``"cuda"`` (tasks hold one GPU each
        and evaluate their batch with :class:`~thintact_masks.fitness_torch.TorchBatchFitness`)
        or ``"auto"`` (``"cuda"`` when the cluster has GPUs).
    """

    def __init__(self, evaluator: Any, address: str = AUTO_ADDRESS, num_cpus: int | None = None,
                 batch_size: int | None = None, cpus_per_task: float = 1.0,
                 max_retries: int = 3, device: str = "auto") -> None:
        if batch_size is not None and batch_size < 1:
            raise MaskDesignError(f"the Ray batch size must be >= 1, got {batch_size}")
        if not cpus_per_task > 0:
            raise MaskDesignError(f"cpus_per_task must be > 0, got {cpus_per_task}")
        if max_retries < 0:
            raise MaskDesignError(f"max_retries must be >= 0, got {max_retries}")
        self._ray = import_ray()
        self._evaluator_ref: Any = None
        self._owns_ray = connect(address, num_cpus)
        self.batch_size = batch_size
        self.cpus_per_task = float(cpus_per_task)
        try:
            self.device = self._cluster_device(device)
        except MaskDesignError:
            self.close()
            raise
        options: dict[str, Any] = {"num_cpus": self.cpus_per_task, "max_retries": max_retries,
                                   "retry_exceptions": False}
        if self.device == "cuda":
            options["num_gpus"] = 1
        self._task = self._ray.remote(evaluate_genes).options(**options)
        t0 = time.perf_counter()
        self._evaluator_ref = self._ray.put(evaluator)
        #: seconds the driver spent putting the evaluator into the object store
        self.put_s = time.perf_counter() - t0
        self.last = GenerationStats()
        self.history: list[GenerationStats] = []

    def _cluster_device(self, device: str) -> str:
        gpus = float(self._ray.cluster_resources().get("GPU", 0.0))
        if device == "auto":
            return "cuda" if gpus > 0 else "cpu"
        if device == "cuda" and gpus <= 0:
            raise MaskDesignError("--device cuda: the Ray cluster has no GPUs; use --device cpu")
        if device not in ("cpu", "cuda"):
            raise MaskDesignError(f"--device must be auto, cpu or cuda, got {device!r}")
        return device

    def cluster_slots(self) -> int:
        """Tasks the cluster can run at once (its CPUs / ``cpus_per_task``, at least 1)."""
        cpus = float(self._ray.cluster_resources().get("CPU", 1.0))
        return max(1, int(cpus // self.cpus_per_task))

    def batches(self, n_genes: int) -> list[slice]:
        """How ``n_genes`` genes are split into tasks (contiguous, in order)."""
        size = self.batch_size or max(1, math.ceil(n_genes / (2 * self.cluster_slots())))
        return [slice(i, min(i + size, n_genes)) for i in range(0, n_genes, size)]

    def __call__(self, genes: np.ndarray) -> np.ndarray:
        """Fitness of every row of ``genes`` (``G × K`` ±1), evaluated on the cluster."""
        ray = self._ray
        genes = np.ascontiguousarray(genes, dtype=np.int8)
        t0 = time.perf_counter()
        parts = self.batches(genes.shape[0])
        refs = [self._task.remote([self._evaluator_ref], genes[s], self.device) for s in parts]
        try:
            results = ray.get(refs)
        except ray.exceptions.RayTaskError as err:
            raise MaskDesignError(f"a fitness task failed: {err.cause!r}") from None
        except ray.exceptions.RayError as err:
            raise MaskDesignError(
                f"fitness tasks were lost after their retries ({type(err).__name__}: "
                f"{str(err).splitlines()[0]}); run the same command again to continue from "
                "the last checkpoint") from None
        stats = GenerationStats(genes.shape[0], len(refs), time.perf_counter() - t0)
        for _, pid, seconds in results:
            stats.compute_s += seconds
            stats.worker_pids.add(pid)
        self.last = stats
        self.history.append(stats)
        return np.concatenate([values for values, _, _ in results])

    def close(self) -> None:
        """Free the evaluator in the object store; shut Ray down if this pool started it."""
        self._evaluator_ref = None
        if self._owns_ray and self._ray.is_initialized():
            self._ray.shutdown()
        self._owns_ray = False

    def __enter__(self) -> RayFitnessPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
