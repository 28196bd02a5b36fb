"""GA operators, checkpoint/resume equivalence and improvement on a tiny problem."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from thintact_masks.errors import MaskDesignError
from thintact_masks.fitness import FitnessEvaluator
from thintact_masks.ga import (
    CHECKPOINT_NAME,
    GAConfig,
    load_checkpoint,
    mutate,
    run_ga,
    tournament_select,
    two_point_crossover,
)


@settings(max_examples=50, deadline=None)
@given(k=st.integers(2, 300), seed=st.integers(0, 2**32 - 1))
def test_crossover_swaps_exactly_one_segment(k: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = np.ones(k, np.int8)
    b = -np.ones(k, np.int8)
    ca, cb, (i, j) = two_point_crossover(a, b, rng)
    assert 0 <= i < j <= k
    expected_a = a.copy()
    expected_a[i:j] = -1
    np.testing.assert_array_equal(ca, expected_a)
    np.testing.assert_array_equal(cb, -expected_a)
    np.testing.assert_array_equal(a, 1)  # parents untouched
    np.testing.assert_array_equal(b, -1)


@settings(max_examples=50, deadline=None)
@given(k=st.integers(10, 800), seed=st.integers(0, 2**32 - 1))
def test_mutation_flips_exactly_ten_loci(k: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    g = (2 * rng.integers(0, 2, k) - 1).astype(np.int8)
    out, loci = mutate(g, 10, rng)
    changed = np.nonzero(out != g)[0]
    assert changed.size == 10
    np.testing.assert_array_equal(changed, loci)
    np.testing.assert_array_equal(out[changed], -g[changed])


def test_tournament_picks_the_fittest_drawn() -> None:
    fitness = np.arange(10.0)
    rng = np.random.default_rng(0)
    assert tournament_select(fitness, 10, rng) == 9
    picks = [tournament_select(fitness, 3, rng) for _ in range(200)]
    assert np.mean(picks) > 4.5 + 1.0  # biased to the fit end


def _quadratic_fitness(target: np.ndarray):
    return lambda phi: float((phi == target).mean())


def test_checkpoint_resume_equals_uninterrupted_run(tmp_path) -> None:
    target = np.random.default_rng(7).choice([-1, 1], 64).astype(np.int8)
    fn = _quadratic_fitness(target)
    full = run_ga(64, GAConfig(population=12, generations=6, seed=5), fn, tmp_path / "full")
    part = run_ga(64, GAConfig(population=12, generations=3, seed=5), fn, tmp_path / "split")
    assert part.generation == 3
    resumed = run_ga(64, GAConfig(population=12, generations=6, seed=5), fn, tmp_path / "split")
    assert resumed.generation == 6
    np.testing.assert_array_equal(resumed.population, full.population)
    np.testing.assert_array_equal(resumed.fitness, full.fitness)
    assert resumed.best_history == full.best_history
    assert resumed.mean_history == full.mean_history
    assert resumed.rng_state == full.rng_state
    assert not list((tmp_path / "split").glob("*.tmp"))
    saved = load_checkpoint(tmp_path / "split")
    assert saved is not None and saved.generation == 6


def test_resume_with_other_settings_is_refused(tmp_path) -> None:
    fn = _quadratic_fitness(np.ones(32, np.int8))
    run_ga(32, GAConfig(population=6, generations=1, seed=1), fn, tmp_path)
    with pytest.raises(MaskDesignError, match="different run"):
        run_ga(32, GAConfig(population=6, generations=2, seed=2), fn, tmp_path)


def test_corrupt_checkpoint_is_reported(tmp_path) -> None:
    (tmp_path / CHECKPOINT_NAME).write_bytes(b"not a zip")
    with pytest.raises(MaskDesignError, match="cannot read checkpoint"):
        load_checkpoint(tmp_path)


def test_threaded_evaluation_gives_the_same_run() -> None:
    fn = _quadratic_fitness(np.random.default_rng(3).choice([-1, 1], 48).astype(np.int8))
    a = run_ga(48, GAConfig(population=10, generations=3, seed=0), fn)
    b = run_ga(48, GAConfig(population=10, generations=3, seed=0), fn, workers=2)
    np.testing.assert_array_equal(a.population, b.population)


@pytest.mark.parametrize("bad", [dict(population=1), dict(generations=-1), dict(elite=8),
                                 dict(crossover_prob=1.5), dict(tournament=0)])
def test_bad_settings_are_refused(bad) -> None:
    config = replace(GAConfig(population=8), **bad)
    with pytest.raises(MaskDesignError):
        config.validate(32)


def test_fitness_improves_over_generations_on_a_tiny_device(tiny_profile) -> None:
    ev = FitnessEvaluator(tiny_profile, 40)
    state = run_ga(40, GAConfig(population=10, generations=8, seed=0), ev.fitness)
    best = np.asarray(state.best_history)
    assert np.all(np.diff(best) >= 0)  # elitism
    assert best[-1] > best[0]
    assert state.best_fitness == pytest.approx(ev.fitness(state.best_phi))


def test_interrupted_run_resumes_to_the_same_result(tmp_path) -> None:
    target = np.random.default_rng(11).choice([-1, 1], 50).astype(np.int8)
    fn = _quadratic_fitness(target)
    config = GAConfig(population=10, generations=5, seed=2)
    full = run_ga(50, config, fn, tmp_path / "full")

    def stop_after_two(state) -> None:
        if state.generation == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_ga(50, config, fn, tmp_path / "cut", progress=stop_after_two)
    saved = load_checkpoint(tmp_path / "cut")
    assert saved is not None and saved.generation == 2
    resumed = run_ga(50, config, fn, tmp_path / "cut")
    np.testing.assert_array_equal(resumed.population, full.population)
    assert resumed.best_history == full.best_history
