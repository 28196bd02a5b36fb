"""``SeparableKernel.apply`` against the plain sum ``Σ_k P_k X Q_kᵀ``: dense terms, terms it
applies through their truncated SVDs, channels sharing a term list, both precisions."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.simulation.separable import SeparableKernel, SeparableTerm, compress_terms


def _terms(rng: np.random.Generator, rows: int, cols: int, n: int, m: int) -> list[SeparableTerm]:
    dense = [SeparableTerm(rng.standard_normal((rows, n)), rng.standard_normal((cols, m)), "coding")
             for _ in range(5)]
    # rank-2 P and Q with P.size ≥ 100 000: applied through their factors
    smooth = SeparableTerm(rng.standard_normal((rows, 2)) @ rng.standard_normal((2, n)),
                           rng.standard_normal((cols, 2)) @ rng.standard_normal((2, m)), "open")
    return dense + [smooth]


@pytest.mark.parametrize("dtype, tol", [("float64", 1e-12), ("float32", 1e-5)])
def test_apply_is_the_sum_of_the_terms(dtype, tol):
    rng = np.random.default_rng(3)
    rows, cols, n, m = 400, 300, 260, 220
    first, second = _terms(rng, rows, cols, n, m), _terms(rng, rows, cols, n, m)
    kernel = SeparableKernel([first, second, first])
    assert kernel.plan(0, dtype).low_rank and kernel.plan(0, dtype).k_dense == 5
    scenes = rng.random((2, n, m, 3))
    got = kernel.apply(scenes, dtype)
    assert got.shape == (2, rows, cols, 3) and got.dtype == np.float64
    for f in range(2):
        for c, terms in enumerate((first, second, first)):
            want = sum(t.P @ scenes[f, :, :, c] @ t.Q.T for t in terms)
            assert np.abs(got[f, :, :, c] - want).max() <= tol * np.abs(want).max()


def test_apply_without_dense_terms():
    rng = np.random.default_rng(4)
    smooth = _terms(rng, 400, 300, 260, 220)[-1:]
    kernel = SeparableKernel([smooth])
    scenes = rng.random((1, 260, 220, 1))
    want = smooth[0].P @ scenes[0, :, :, 0] @ smooth[0].Q.T
    np.testing.assert_allclose(kernel.apply(scenes)[0, :, :, 0], want, rtol=1e-12, atol=1e-9)


def test_compress_terms_keeps_the_operator():
    rng = np.random.default_rng(5)
    base = [(rng.random((30, 20)), rng.random((25, 15))) for _ in range(6)]
    terms = [SeparableTerm(sum(w * b[0] for w, b in zip(rng.standard_normal(6), base, strict=True)),
                           base[k % 6][1].copy(), "coding") for k in range(40)]
    out = compress_terms(terms, 1e-10)
    assert len(out) <= 6
    x = rng.random((20, 15))
    want = sum(t.P @ x @ t.Q.T for t in terms)
    got = sum(t.P @ x @ t.Q.T for t in out)
    assert np.abs(got - want).max() <= 1e-9 * np.abs(want).max()


def test_compressing_terms_that_are_all_zero_keeps_one_zero_term():
    """A mask shifted out of view gives only zero terms; their SVD was empty and indexing it
    ended the build in IndexError (exit 1) before the kernel's size could be refused."""
    zeros = [SeparableTerm(np.zeros((4, 3)), np.zeros((5, 2)), "coding") for _ in range(3)]
    live = [SeparableTerm(np.ones((4, 3)), np.ones((5, 2)), "open") for _ in range(2)]
    out = compress_terms(zeros + live)
    coding = [t for t in out if t.part == "coding"]
    assert len(coding) == 1 and not coding[0].P.any() and coding[0].P.shape == (4, 3)
    opened = [t for t in out if t.part == "open"]
    assert len(opened) == 1
    np.testing.assert_allclose(np.kron(opened[0].P, opened[0].Q), 2 * np.ones((20, 6)))
