"""t2s-closed-form: the exact full-T2S Tikhonov minimiser, checked against a dense solve."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.errors import CalibrationError, InvalidValueError
from thintact_sdk.reconstruction.decoders import (
    ArrayBackend,
    T2SClosedFormDecoder,
    T2SIterativeDecoder,
)
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices


def _low_rank_open_matrices(seed: int = 0) -> SystemMatrices:
    """Small T2S matrices whose open part has rank 2 per axis (like a smooth blur)."""
    rng = np.random.default_rng(seed)
    r, s, n, m = 30, 34, 12, 14

    def smooth(rows: int, cols: int) -> np.ndarray:
        return rng.random((rows, 2)) @ rng.random((2, cols)) * 3

    po = np.stack([smooth(r, n) for _ in range(2)])
    qo = np.stack([smooth(s, m) for _ in range(2)])
    pc = rng.standard_normal((2, r, n))
    qc = rng.standard_normal((2, s, m))
    return SystemMatrices(po, qo, pc, qc)


def _dense_solution(sm: SystemMatrices, y: np.ndarray, tau: float) -> np.ndarray:
    n, m = sm.scene_shape
    out = np.empty((n, m, sm.channels))
    for c in range(sm.channels):
        po, qo, pc, qc = (a.astype(np.float64) for a in sm.channel(c))
        a = np.kron(qo, po) + np.kron(qc, pc)  # acts on column-major vec(X)
        rhs = a.T @ y[..., c].astype(np.float64).ravel(order="F")
        out[..., c] = np.linalg.solve(a.T @ a + tau * np.eye(n * m), rhs).reshape(n, m, order="F")
    return out


def _dense_generalised(sm: SystemMatrices, y: np.ndarray, tau: float, prior: ScenePrior) -> np.ndarray:
    """``argmin ‖A x − y‖² + τ‖(W_R ⊗ W_L) x‖²`` by a dense solve (column-major ``vec``)."""
    n, m = sm.scene_shape
    w = np.kron(prior.weight(m), prior.weight(n))
    out = np.empty((n, m, sm.channels))
    for c in range(sm.channels):
        po, qo, pc, qc = (a.astype(np.float64) for a in sm.channel(c))
        a = np.kron(qo, po) + np.kron(qc, pc)
        rhs = a.T @ y[..., c].astype(np.float64).ravel(order="F")
        out[..., c] = np.linalg.solve(a.T @ a + tau * w.T @ w, rhs).reshape(n, m, order="F")
    return out


@pytest.mark.parametrize("prior", [ScenePrior(1.0, 3.0), ScenePrior(1.5, 1.0)])
def test_scene_prior_matches_the_dense_generalised_tikhonov(prior) -> None:
    sm = _low_rank_open_matrices(6)
    rng = np.random.default_rng(7)
    y = sm.forward(rng.random((*sm.scene_shape, 2))) + rng.standard_normal((*sm.sensor_shape, 2)) * 0.5
    tau = 3.0
    exact = _dense_generalised(sm, y, tau, prior)
    plain = _dense_solution(sm, y, tau)
    assert np.abs(exact - plain).max() > 0.05 * np.abs(exact).max()  # the prior changes the answer
    dec = T2SClosedFormDecoder(sm, tau, ArrayBackend("numpy", "float64"), prior=prior)
    np.testing.assert_allclose(dec.decode(y), exact, atol=1e-5 * np.abs(exact).max())
    np.testing.assert_allclose(dec.decode(y + 64.0, 64.0), exact, atol=1e-5 * np.abs(exact).max())
    dec.set_tau(0.5)  # set_tau keeps the prior
    np.testing.assert_allclose(dec.decode(y), _dense_generalised(sm, y, 0.5, prior),
                               atol=1e-5 * np.abs(exact).max())
    # α = 0 is plain Tikhonov
    flat = T2SClosedFormDecoder(sm, tau, ArrayBackend("numpy", "float64"), prior=ScenePrior(0.0, 1.0))
    np.testing.assert_allclose(flat.decode(y), plain, atol=1e-5 * np.abs(plain).max())


def test_scene_prior_json_round_trip_and_refusals() -> None:
    prior = ScenePrior(0.75, 8.0)
    assert ScenePrior.from_json(prior.to_json()) == prior
    np.testing.assert_allclose(prior.weight(9) @ prior.inverse_weight(9), np.eye(9), atol=1e-12)
    for bad in ({"kind": "dct-power", "alpha": -1, "k0": 1}, {"kind": "dct-power", "alpha": 1, "k0": 0},
                {"kind": "other"}, {"kind": "dct-power", "alpha": "x", "k0": 1}, [1, 2]):
        with pytest.raises(CalibrationError, match="scene prior"):
            ScenePrior.from_json(bad, "scene prior")


@pytest.mark.parametrize("tau", [1e-3, 10.0])
def test_matches_the_dense_minimiser(tau) -> None:
    sm = _low_rank_open_matrices()
    rng = np.random.default_rng(1)
    x = rng.random((*sm.scene_shape, 2))
    y = sm.forward(x) + rng.standard_normal((*sm.sensor_shape, 2)) * 0.5
    dec = T2SClosedFormDecoder(sm, tau, ArrayBackend("numpy", "float64"))
    assert dec.info["open_rank"][0] == [2, 2]
    exact = _dense_solution(sm, y, tau)
    np.testing.assert_allclose(dec.decode(y), exact, atol=1e-5 * np.abs(exact).max())
    # float32 on both backends stays close, and the black level folds in exactly
    for be in (ArrayBackend("numpy"), ArrayBackend("torch")):
        d32 = T2SClosedFormDecoder(sm, tau, be)
        np.testing.assert_allclose(d32.decode(y.astype(np.float32)), exact, atol=1e-2 * np.abs(exact).max())
        np.testing.assert_allclose(d32.decode((y + 64).astype(np.float32), 64.0), exact,
                                   atol=1e-2 * np.abs(exact).max())


def test_iterative_nesterov_tends_to_the_closed_form() -> None:
    sm = _low_rank_open_matrices(2)
    x = np.random.default_rng(3).random((*sm.scene_shape, 2))
    y = sm.forward(x)
    tau = 30.0  # well conditioned enough for 800 Nesterov steps to get close
    closed = T2SClosedFormDecoder(sm, tau, ArrayBackend("numpy", "float64")).decode(y)
    gaps = []
    for iters in (50, 400, 3000):
        it = T2SIterativeDecoder(sm, tau, iterations=iters, backend=ArrayBackend("numpy", "float64"))
        gaps.append(float(np.abs(it.decode(y) - closed).max()))
    assert gaps[0] > gaps[1] > gaps[2]
    assert gaps[2] < 5e-3 * np.abs(closed).max()


def test_truncated_open_rank_is_reported() -> None:
    sm = _low_rank_open_matrices(4)
    rng = np.random.default_rng(5)
    full_rank = SystemMatrices(sm.Po + 1e-3 * rng.random(sm.Po.shape), sm.Qo, sm.Pc, sm.Qc)
    dec = T2SClosedFormDecoder(full_rank, 1.0, max_open_rank=2)
    assert dec.info["open_rank"][0] == [2, 2]
    assert 0 < dec.info["dropped_open_sv"][0][0] < 1e-2


def test_iterate_reproduces_the_iterative_decoder() -> None:
    sm = _low_rank_open_matrices(6)
    rng = np.random.default_rng(7)
    y = sm.forward(rng.random((*sm.scene_shape, 2))) + rng.standard_normal((*sm.sensor_shape, 2))
    be = ArrayBackend("numpy", "float64")
    closed = T2SClosedFormDecoder(sm, 30.0, be)
    plain = T2SIterativeDecoder(sm, 30.0, iterations=100, backend=be).decode(y)
    fast = closed.iterate(y, iterations=100)
    np.testing.assert_allclose(fast, plain, atol=1e-4 * np.abs(plain).max())


def test_set_tau_equals_a_fresh_decoder() -> None:
    from thintact_sdk.reconstruction.decoders import NonIterativeDecoder
    from thintact_sdk.reconstruction.synthetic_matrices import frequency_split_matrices

    sm = _low_rank_open_matrices(8)
    y = sm.forward(np.random.default_rng(9).random((*sm.scene_shape, 2)))
    dec = T2SClosedFormDecoder(sm, 1.0, ArrayBackend("numpy", "float64"))
    dec.set_tau(25.0)
    fresh = T2SClosedFormDecoder(sm, 25.0, ArrayBackend("numpy", "float64"))
    np.testing.assert_allclose(dec.decode(y), fresh.decode(y), rtol=1e-6, atol=1e-9)
    sm2, jf = frequency_split_matrices((40, 44), (12, 14), (6, 7), seed=4)
    y2 = sm2.forward(np.random.default_rng(1).random((12, 14, 3)))
    ni = NonIterativeDecoder(sm2, jf, 1.0, ArrayBackend("numpy", "float64"))
    ni.set_tau(5.0)
    np.testing.assert_allclose(ni.decode(y2), NonIterativeDecoder(sm2, jf, 5.0, ArrayBackend(
        "numpy", "float64")).decode(y2), rtol=1e-6, atol=1e-9)


def test_exact_in_any_gauge_of_the_same_operator() -> None:
    """``[Po Pc]·A``, ``[Qo Qc]·A⁻ᵀ`` is the same device: the decoder must give the same
    (exact) minimiser although Po, Qo then carry part of the coding term (full rank)."""
    rng = np.random.default_rng(4)
    r, s, n, m = 30, 34, 12, 14

    def blur(rows: int, cols: int, width: float) -> np.ndarray:
        u, v = np.linspace(0, 1, rows)[:, None], np.linspace(0, 1, cols)[None, :]
        return np.exp(-((u - v) ** 2) / (2 * width**2))

    po, qo = blur(r, n, 0.6)[None], blur(s, m, 0.5)[None]
    pc, qc = rng.standard_normal((1, r, n)), rng.standard_normal((1, s, m))
    a = np.array([[1.0, 0.4], [0.7, 1.0]])  # mixes the coding term into the open one
    b = np.linalg.inv(a).T
    mixed = SystemMatrices(po * a[0, 0] + pc * a[1, 0], qo * b[0, 0] + qc * b[1, 0],
                           po * a[0, 1] + pc * a[1, 1], qo * b[0, 1] + qc * b[1, 1])
    x = rng.random((n, m, 1))
    y = mixed.forward(x) + rng.standard_normal((r, s, 1)) * 0.05
    tau = 0.1
    exact = _dense_solution(mixed, y, tau)
    np.testing.assert_allclose(_dense_solution(SystemMatrices(po, qo, pc, qc), y, tau), exact, atol=1e-8)
    dec = T2SClosedFormDecoder(mixed, tau, ArrayBackend("numpy", "float64"), max_open_rank=4)
    assert max(dec.info["dropped_open_sv"][0]) < 1e-3
    np.testing.assert_allclose(dec.decode(y), exact, atol=1e-4 * np.abs(exact).max())


def test_a_tau_per_channel_decodes_each_channel_at_its_own_tau() -> None:
    from thintact_sdk.reconstruction.decoders import NonIterativeDecoder

    sm = _low_rank_open_matrices(5)
    rng = np.random.default_rng(6)
    y = sm.forward(rng.random((*sm.scene_shape, 2))) + rng.standard_normal((*sm.sensor_shape, 2)) * 0.5
    be = ArrayBackend("numpy", "float64")
    for make in (lambda t: T2SClosedFormDecoder(sm, t, be), lambda t: NonIterativeDecoder(sm, None, t, be)):
        both = make([0.01, 30.0])
        np.testing.assert_allclose(both.decode(y)[..., 0], make(0.01).decode(y)[..., 0], rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(both.decode(y)[..., 1], make(30.0).decode(y)[..., 1], rtol=1e-6, atol=1e-9)
        changed = make(1.0)
        changed.set_tau([0.01, 30.0])
        np.testing.assert_allclose(changed.decode(y), both.decode(y), rtol=1e-6, atol=1e-9)
        with pytest.raises(InvalidValueError):
            changed.set_tau([1.0, 2.0, 3.0])  # three values for two channels
        with pytest.raises(InvalidValueError):
            changed.set_tau([1.0, 0.0])


@pytest.mark.parametrize("block_bytes", [1 << 18, 200])
def test_blocked_numpy_solve_is_the_generic_solve(monkeypatch: pytest.MonkeyPatch, block_bytes: int) -> None:
    """numpy's cache-blocked frame solve (the products written into the padded coefficients,
    scale / project / correct per block of rows) gives the generic path's answer: float64 to
    1e-10, float32 to float32 rounding; one block and many, with the coding modes truncated
    (zero-padded coefficients) and a black level."""
    import thintact_sdk.reconstruction.decoders.t2s_closed_form as t2s

    monkeypatch.setattr(t2s, "BLOCK_BYTES", block_bytes)
    sm = _low_rank_open_matrices(3)
    rng = np.random.default_rng(4)
    y = sm.forward(rng.random((*sm.scene_shape, 2))) + 64.0 + rng.standard_normal((*sm.sensor_shape, 2))
    for dtype, tol in (("float64", 1e-10), ("float32", 2e-5)):
        blocked = T2SClosedFormDecoder(sm, 3000.0, ArrayBackend("numpy", dtype), mode_rtol=0.2)
        generic = T2SClosedFormDecoder(sm, 3000.0, ArrayBackend("torch", dtype), mode_rtol=0.2)
        assert blocked.kept_modes == generic.kept_modes == (10, 11)  # of 12 × 14: zero padding
        assert t2s._block_rows(2, 14, 8) == (8 if block_bytes == 200 else (1 << 18) // 224)
        for out_b, out_g in ((blocked.decode(y.astype(dtype), 64.0), generic.decode(y.astype(dtype), 64.0)),
                             (blocked.decode(y.astype(dtype) - 64), generic.decode(y.astype(dtype) - 64))):
            np.testing.assert_allclose(out_b, out_g, rtol=0, atol=tol * np.abs(out_g).max())
