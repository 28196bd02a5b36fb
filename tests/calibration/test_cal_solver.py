"""Algorithms 1-3 (and the least-squares variant) on synthetic T2S slit scans."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.calibration import synthetic
from thintact_sdk.calibration.gauge import balance_frobenius, fix_gauge, operator_error, term_errors
from thintact_sdk.calibration.lowrank import compress
from thintact_sdk.calibration.slits import ChannelSlits, SlitStack
from thintact_sdk.calibration.solver import ChannelMatrices, solve_channel
from thintact_sdk.errors import CalibrationError


def _slits(truth: ChannelMatrices, yh: list[np.ndarray], yv: list[np.ndarray]) -> ChannelSlits:
    n, m = truth.Po.shape[1], truth.Qo.shape[1]
    h = SlitStack.from_images(list(range(n)), [np.ones(m)] * n, [compress(y) for y in yh])
    v = SlitStack.from_images(list(range(m)), [np.ones(n)] * m, [compress(y.T) for y in yv])
    return ChannelSlits(h, v, n, m)


def test_lowrank_compression_keeps_products() -> None:
    rng = np.random.default_rng(3)
    y = rng.standard_normal((40, 3)) @ rng.standard_normal((3, 50)) + 1e-3 * rng.standard_normal((40, 50))
    lr = compress(y, rank=4)
    q = rng.standard_normal(50)
    np.testing.assert_allclose(lr.left @ (lr.right.T @ q), y @ q, rtol=1e-3, atol=0.05)
    assert lr.energy == pytest.approx(float(np.sum(y * y)))
    assert lr.captured_energy == pytest.approx(lr.energy, rel=1e-4)
    assert np.allclose(lr.transposed().dense(), lr.dense().T)


@pytest.mark.parametrize("method", ["paper", "lsq"])
def test_noiseless_slits_recover_the_operator(method: str) -> None:
    truth = synthetic.system(seed=2)
    est, rep = solve_channel(_slits(truth, *synthetic.slit_images(truth)), method=method, max_iter=100)
    assert rep.converged
    assert operator_error(est, truth) < 1e-6
    errs = term_errors(est, truth)
    assert max(errs.values()) < 1e-5, errs


def test_noisy_slits_converge_and_lsq_is_not_worse_than_paper() -> None:
    truth = synthetic.system(seed=4, gain_dn=30.0)
    data = synthetic.slit_images(truth, noise_dn=2.0, electrons_per_dn=4.0, seed=5)
    errs = {}
    for method in ("paper", "lsq"):
        est, rep = solve_channel(_slits(truth, *data), method=method)
        assert rep.converged
        assert rep.residual_history[-1] <= rep.residual_history[0] * (1 + 1e-6)
        errs[method] = operator_error(est, truth)
    assert errs["lsq"] < 0.02
    assert errs["lsq"] <= errs["paper"] * 1.001


def test_gauge_fix_keeps_products_and_balances_norms() -> None:
    truth = synthetic.system(seed=7)
    rng = np.random.default_rng(0)
    a = rng.standard_normal((2, 2)) + 2 * np.eye(2)
    b = np.linalg.inv(a).T
    mixed = ChannelMatrices(
        truth.Po * a[0, 0] + truth.Pc * a[1, 0],
        truth.Qo * b[0, 0] + truth.Qc * b[1, 0],
        truth.Po * a[0, 1] + truth.Pc * a[1, 1],
        truth.Qo * b[0, 1] + truth.Qc * b[1, 1],
    )
    assert operator_error(mixed, truth) < 1e-9
    fixed = fix_gauge(mixed)
    assert operator_error(fixed, truth) < 1e-9
    assert np.linalg.norm(fixed.Po) == pytest.approx(np.linalg.norm(fixed.Qo))
    assert np.linalg.norm(fixed.Pc) == pytest.approx(np.linalg.norm(fixed.Qc))
    # the canonical gauge is unique: the mixed set and the truth land on the same matrices
    ref = fix_gauge(truth)
    np.testing.assert_allclose(fixed.Po, ref.Po, atol=1e-9 * np.abs(ref.Po).max())
    np.testing.assert_allclose(fixed.Qc, ref.Qc, atol=1e-9 * np.abs(ref.Qc).max())
    # the smooth open term is the physical one (up to a small mixing)
    errs = term_errors(fix_gauge(balance_frobenius(truth)), truth)
    assert errs["open_term"] < 1e-9


def test_missing_slits_are_named() -> None:
    truth = synthetic.system(seed=1)
    yh, yv = synthetic.slit_images(truth)
    n, m = truth.Po.shape[1], truth.Qo.shape[1]
    h = SlitStack.from_images(list(range(1, n)), [np.ones(m)] * (n - 1), [compress(y) for y in yh[1:]])
    v = SlitStack.from_images(list(range(m)), [np.ones(n)] * m, [compress(y.T) for y in yv])
    with pytest.raises(CalibrationError, match=r"scene row\(s\) 0 "):
        solve_channel(ChannelSlits(h, v, n, m))


def test_duplicate_and_dimmed_slits_are_combined() -> None:
    truth = synthetic.system(seed=8)
    yh, yv = synthetic.slit_images(truth)
    n, m = truth.Po.shape[1], truth.Qo.shape[1]
    # every row shown twice, once at half brightness; columns at 0.7
    idx = list(range(n)) * 2
    prof = [np.ones(m)] * n + [np.full(m, 0.5)] * n
    imgs = [compress(y) for y in yh] + [compress(0.5 * y) for y in yh]
    h = SlitStack.from_images(idx, prof, imgs)
    v = SlitStack.from_images(list(range(m)), [np.full(n, 0.7)] * m, [compress(0.7 * y.T) for y in yv])
    est, rep = solve_channel(ChannelSlits(h, v, n, m))
    assert rep.converged
    assert operator_error(est, truth) < 1e-6
