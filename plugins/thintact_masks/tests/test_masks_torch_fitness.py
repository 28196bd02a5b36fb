"""The batched torch fitness (the GPU path of the GA) computes the numpy fitness: tested on the
CPU here; the CUDA test runs where a GPU is present and is skipped cleanly elsewhere."""

from __future__ import annotations

import numpy as np
import pytest
from mask_profiles import make_profile
from thintact_masks.errors import MaskDesignError
from thintact_masks.fitness import FitnessEvaluator
from thintact_masks.fitness_torch import TorchBatchFitness, cuda_available, resolve_device

torch = pytest.importorskip("torch")


def _genes(n: int, k: int, seed: int = 1) -> np.ndarray:
    return (2 * np.random.default_rng(seed).integers(0, 2, (n, k)) - 1).astype(np.int8)


def test_torch_batch_on_cpu_equals_the_numpy_fitness() -> None:
    ev = FitnessEvaluator(make_profile())
    genes = _genes(5, ev.K)
    batch = TorchBatchFitness(ev, "cpu", max_batch=2)(genes)  # 3 device batches: 2 + 2 + 1
    expected = np.array([ev.fitness(g) for g in genes])
    np.testing.assert_allclose(batch, expected, rtol=1e-9)
    assert len(set(np.round(expected, 12))) > 1  # the genes are told apart


def test_device_choice_without_a_gpu() -> None:
    if cuda_available():
        pytest.skip("a GPU is present: the CPU fallback is not what runs here")
    assert resolve_device("auto") == "cpu" and resolve_device("cpu") == "cpu"
    with pytest.raises(MaskDesignError, match="cuda"):
        resolve_device("cuda")
    with pytest.raises(MaskDesignError, match="--device must be one of"):
        resolve_device("tpu")


@pytest.mark.skipif(not cuda_available(), reason="no CUDA device on this host")
def test_torch_batch_on_cuda_matches_the_cpu_fitness() -> None:
    ev = FitnessEvaluator(make_profile())
    genes = _genes(4, ev.K)
    expected = np.array([ev.fitness(g) for g in genes])
    got = TorchBatchFitness(ev, "cuda")(genes)
    # eigenvector signs follow one convention on every LAPACK, so the noise draw is the same
    np.testing.assert_allclose(got, expected, rtol=1e-6)
