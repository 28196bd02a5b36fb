"""The paper's genetic algorithm over mask vectors φ ∈ {±1}^K, with atomic checkpoints.

Operators (paper §III-C-1 and §V-B):

- gene: φ itself (K loci of ±1);
- crossover (probability 0.8 per pair): two loci ``i < j`` are drawn and the segment
  ``[i, j)`` is exchanged between the two parents (two-point crossover);
- mutation (probability 0.1 per child): ``s = 10`` distinct loci are drawn and inverted.

Our choices where the paper is silent: tournament selection (size 3) of each parent,
elitism (the best 2 individuals pass unchanged, so the best fitness never decreases), and
the initial population is random (seeded) plus the MLS baseline as one individual (so the
result is never worse than the baseline). Everything draws from one numpy ``PCG64``
generator whose state is checkpointed with the population after every generation, so a
resumed run reproduces an uninterrupted one exactly.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_masks.errors import MaskDesignError
from thintact_masks.mls import mls_sequence, repeat_to_length
from thintact_sdk.plugin_support import read_npz, safe_json

CHECKPOINT_NAME = "checkpoint.npz"
CHECKPOINT_FORMAT = "thintact-ga-checkpoint/1"


@dataclass
class GAConfig:
    """Genetic-algorithm settings (paper values by default).

    Attributes
    ----------
    population
        Individuals per generation (paper 200).
    generations
        Generations after the initial one (paper 2000).
    crossover_prob
        Probability that a selected pair exchanges a segment (paper 0.8).
    mutation_prob
        Probability that a child is mutated (paper 0.1).
    mutation_loci
        Loci inverted by one mutation (paper 10).
    tournament
        Tournament size of the parent selection.
    elite
        Best individuals copied unchanged into the next generation.
    seed
        Seed of the run's random generator.
    include_mls
        Put the MLS baseline into the initial population.
    """

    population: int = 200
    generations: int = 2000
    crossover_prob: float = 0.8
    mutation_prob: float = 0.1
    mutation_loci: int = 10
    tournament: int = 3
    elite: int = 2
    seed: int = 0
    include_mls: bool = True

    def validate(self, K: int) -> None:  # noqa: N803
        """Raise :class:`MaskDesignError` naming the first setting that cannot work."""
        if self.population < 2:
            raise MaskDesignError(f"population must be at least 2, got {self.population}")
        if self.generations < 0:
            raise MaskDesignError(f"generations must be >= 0, got {self.generations}")
        if not (0.0 <= self.crossover_prob <= 1.0 and 0.0 <= self.mutation_prob <= 1.0):
            raise MaskDesignError("crossover and mutation probabilities must lie in [0, 1]")
        if not 1 <= self.mutation_loci <= K:
            raise MaskDesignError(f"mutation_loci must be in 1..K={K}, got {self.mutation_loci}")
        if not 1 <= self.tournament <= self.population:
            raise MaskDesignError(f"tournament must be in 1..population, got {self.tournament}")
        if not 0 <= self.elite < self.population:
            raise MaskDesignError(f"elite must be in 0..population-1, got {self.elite}")
        if K < 2:
            raise MaskDesignError(f"K must be at least 2, got {K}")

    def resume_key(self) -> dict[str, Any]:
        """The settings a checkpoint must share with a run that resumes it (all but generations)."""
        d = asdict(self)
        d.pop("generations")
        return d


def two_point_crossover(a: np.ndarray, b: np.ndarray, rng: np.random.Generator
                        ) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Exchange the segment ``[i, j)`` between copies of ``a`` and ``b`` (``i < j`` random).

    Returns the two children and ``(i, j)``.
    """
    k = a.shape[0]
    i, j = sorted(int(x) for x in rng.choice(k + 1, size=2, replace=False))
    ca, cb = a.copy(), b.copy()
    ca[i:j], cb[i:j] = b[i:j], a[i:j]
    return ca, cb, (i, j)


def mutate(g: np.ndarray, n_loci: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Invert ``n_loci`` distinct random loci of a copy of ``g``; returns it and the loci."""
    loci = np.sort(rng.choice(g.shape[0], size=n_loci, replace=False))
    out = g.copy()
    out[loci] = -out[loci]
    return out, loci


def tournament_select(fitness: np.ndarray, size: int, rng: np.random.Generator) -> int:
    """Index of the fittest of ``size`` individuals drawn without replacement (ties: lowest index)."""
    idx = np.sort(rng.choice(fitness.shape[0], size=size, replace=False))
    return int(idx[int(np.argmax(fitness[idx]))])


@dataclass
class GAState:
    """A GA run after ``generation`` completed generations (0 = the evaluated initial one).

    Attributes
    ----------
    generation
        Completed generations.
    population
        ``P × K`` int8 genes.
    fitness
        ``(P,)`` fitness of each gene.
    best_history, mean_history
        Best and mean fitness of every generation so far (``generation + 1`` entries).
    rng_state
        The numpy bit-generator state to continue from.
    elapsed_s
        Wall time spent in generations so far, s.
    """

    generation: int
    population: np.ndarray
    fitness: np.ndarray
    best_history: list[float]
    mean_history: list[float]
    rng_state: dict[str, Any]
    elapsed_s: float = 0.0
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def best_index(self) -> int:
        return int(np.argmax(self.fitness))

    @property
    def best_phi(self) -> np.ndarray:
        return self.population[self.best_index].copy()

    @property
    def best_fitness(self) -> float:
        return float(self.fitness[self.best_index])


FitnessFn = Callable[[np.ndarray], float]
#: ``G × K`` int8 genes → ``(G,)`` fitness, in order (a Ray pool, a batched torch evaluator)
BatchFitnessFn = Callable[[np.ndarray], np.ndarray]


def evaluate_population(population: np.ndarray, fitness_fn: FitnessFn,
                        known: dict[bytes, float] | None = None, workers: int = 1,
                        batch_fitness: BatchFitnessFn | None = None) -> np.ndarray:
    """Fitness of every row of ``population``.

    Genes found in ``known`` (and duplicates) are evaluated once; with ``workers > 1`` the
    new genes are evaluated concurrently in threads (numpy releases the GIL in LAPACK), the
    results being the same as a serial evaluation. With ``batch_fitness`` the new genes go
    to it in one ``G × K`` array instead (``fitness_fn`` and ``workers`` are then unused).
    """
    known = {} if known is None else known
    todo: dict[bytes, np.ndarray] = {}
    for g in population:
        key = g.tobytes()
        if key not in known and key not in todo:
            todo[key] = g
    if batch_fitness is not None:
        values = _batch_values(batch_fitness, todo) if todo else []
    elif workers > 1 and len(todo) > 1:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            values = list(pool.map(fitness_fn, todo.values()))
    else:
        values = [fitness_fn(g) for g in todo.values()]
    for key, value in zip(todo, values, strict=True):
        known[key] = float(value)
    return np.array([known[g.tobytes()] for g in population])


def _batch_values(batch_fitness: BatchFitnessFn, todo: dict[bytes, np.ndarray]) -> list[float]:
    genes = np.stack(list(todo.values()))
    values = np.asarray(batch_fitness(genes), np.float64)
    if values.shape != (genes.shape[0],):
        raise MaskDesignError(f"the batch fitness returned shape {values.shape} for "
                              f"{genes.shape[0]} genes")
    return [float(v) for v in values]


def initial_state(K: int, config: GAConfig, fitness_fn: FitnessFn,  # noqa: N803
                  workers: int = 1, batch_fitness: BatchFitnessFn | None = None) -> GAState:
    """Seeded random initial population (plus the MLS baseline), evaluated."""
    config.validate(K)
    rng = np.random.default_rng(config.seed)
    pop = (2 * rng.integers(0, 2, size=(config.population, K)) - 1).astype(np.int8)
    if config.include_mls:
        pop[0] = repeat_to_length(mls_sequence(8), K)
    t0 = time.perf_counter()
    fit = evaluate_population(pop, fitness_fn, workers=workers, batch_fitness=batch_fitness)
    return GAState(0, pop, fit, [float(fit.max())], [float(fit.mean())],
                   dict(rng.bit_generator.state), time.perf_counter() - t0)


def next_generation(state: GAState, config: GAConfig, fitness_fn: FitnessFn,
                    workers: int = 1, batch_fitness: BatchFitnessFn | None = None) -> GAState:
    """One generation: elitism, tournament selection, crossover, mutation, evaluation."""
    rng = np.random.default_rng()
    rng.bit_generator.state = state.rng_state
    t0 = time.perf_counter()
    order = np.argsort(-state.fitness, kind="stable")
    children = [state.population[i].copy() for i in order[: config.elite]]
    while len(children) < config.population:
        a = state.population[tournament_select(state.fitness, config.tournament, rng)]
        b = state.population[tournament_select(state.fitness, config.tournament, rng)]
        if rng.random() < config.crossover_prob:
            a, b, _ = two_point_crossover(a, b, rng)
        for child in (a, b):
            if rng.random() < config.mutation_prob:
                child, _ = mutate(child, config.mutation_loci, rng)
            children.append(np.array(child, np.int8, copy=True))
    pop = np.stack(children[: config.population])
    known = {g.tobytes(): float(f) for g, f in zip(state.population, state.fitness, strict=True)}
    fit = evaluate_population(pop, fitness_fn, known, workers, batch_fitness)
    return GAState(state.generation + 1, pop, fit,
                   state.best_history + [float(fit.max())],
                   state.mean_history + [float(fit.mean())],
                   dict(rng.bit_generator.state),
                   state.elapsed_s + time.perf_counter() - t0, state.meta)


# -- checkpoints -----------------------------------------------------------------------------
def save_checkpoint(out_dir: str | os.PathLike[str], state: GAState) -> Path:
    """Write ``out_dir/checkpoint.npz`` atomically (temporary file, fsync, rename)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / CHECKPOINT_NAME
    tmp = out / (CHECKPOINT_NAME + ".tmp")
    meta = {"format": CHECKPOINT_FORMAT, "generation": state.generation,
            "rng_state": state.rng_state, "elapsed_s": state.elapsed_s, "meta": state.meta}
    with open(tmp, "wb") as f:
        np.savez(f, population=state.population, fitness=state.fitness,
                 best_history=np.asarray(state.best_history),
                 mean_history=np.asarray(state.mean_history),
                 meta=np.array(json.dumps(meta)))
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    return path


def load_checkpoint(out_dir: str | os.PathLike[str]) -> GAState | None:
    """The checkpoint in ``out_dir``, or ``None`` when there is none."""
    path = Path(out_dir) / CHECKPOINT_NAME
    if not path.is_file():
        return None
    hint = "; delete it to start over"
    try:
        z = read_npz(path, what="GA checkpoint", error=MaskDesignError,
                     members=("population", "fitness", "best_history", "mean_history", "meta"),
                     kinds={"meta": "U", "population": "biu", "fitness": "fiu",
                            "best_history": "fiu", "mean_history": "fiu"})
    except MaskDesignError as err:
        raise MaskDesignError(f"cannot read checkpoint {path}: {err}{hint}") from None
    meta = safe_json.loads(str(z["meta"]), f"checkpoint {path} member 'meta'", MaskDesignError)
    if not isinstance(meta, dict) or meta.get("format") != CHECKPOINT_FORMAT:
        raise MaskDesignError(f"{path}: not a {CHECKPOINT_FORMAT} checkpoint")
    try:
        if not isinstance(meta["rng_state"], dict) or not isinstance(meta.get("meta", {}), dict):
            raise TypeError("'rng_state' and 'meta' must be JSON objects")
        return GAState(int(meta["generation"]), z["population"].astype(np.int8),
                       z["fitness"].astype(np.float64), z["best_history"].tolist(),
                       z["mean_history"].tolist(), meta["rng_state"],
                       float(meta["elapsed_s"]), meta.get("meta", {}))
    except (ValueError, KeyError, TypeError) as err:
        raise MaskDesignError(f"cannot read checkpoint {path}: {err!r}{hint}") from None


ProgressFn = Callable[[GAState], None]


def run_ga(K: int, config: GAConfig, fitness_fn: FitnessFn,  # noqa: N803
           out_dir: str | os.PathLike[str] | None = None, run_key: dict[str, Any] | None = None,
           progress: ProgressFn | None = None, workers: int = 1,
           batch_fitness: BatchFitnessFn | None = None) -> GAState:
    """Run (or resume) the GA up to ``config.generations`` generations.

    Parameters
    ----------
    K
        Gene length.
    config
        :class:`GAConfig`.
    fitness_fn
        φ (``(K,)`` int8 ±1) → fitness (higher is better); must be deterministic.
    out_dir
        Checkpoint directory: when it holds a checkpoint of the same run (same ``run_key``
        and GA settings other than ``generations``) the run continues from it; a checkpoint
        is written after every generation.
    run_key
        What identifies the run besides the GA settings (profile hash, fitness settings, K).
    progress
        Called with the state after the initial population and after every generation.
    workers
        Individuals evaluated concurrently (does not change the result).
    batch_fitness
        Evaluates each generation's new genes in one call instead of ``fitness_fn``
        (:class:`thintact_masks.ray_pool.RayFitnessPool`, :class:`thintact_masks.fitness_torch.
        TorchBatchFitness`); it must give the values ``fitness_fn`` would. The GA's random
        draws stay here, in the driver, so the run does not depend on where genes are evaluated.
    """
    config.validate(K)
    key = {"ga": config.resume_key(), "K": K, **(run_key or {})}
    key = json.loads(json.dumps(key))
    state = load_checkpoint(out_dir) if out_dir is not None else None
    if state is not None:
        if state.meta.get("run_key") != key:
            raise MaskDesignError(
                f"the checkpoint in {out_dir} belongs to a different run (other profile, K, seed "
                "or settings); use another --out directory or the same settings")
    else:
        state = initial_state(K, config, fitness_fn, workers, batch_fitness)
        state.meta = {"run_key": key}
        if out_dir is not None:
            save_checkpoint(out_dir, state)
    if progress is not None:
        progress(state)
    while state.generation < config.generations:
        state = next_generation(state, config, fitness_fn, workers, batch_fitness)
        if out_dir is not None:
            save_checkpoint(out_dir, state)
        if progress is not None:
            progress(state)
    return state
