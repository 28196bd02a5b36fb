"""Issue 36: the joint filter's Adam refinement with the gradient written out and scipy's fast
DCT (no dense DCT matrices) has torch's loss and gradient, and trains as well."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.reconstruction.dct import SeparableDCT, dct2
from thintact_sdk.reconstruction.filter_training import (
    _closed_form,
    _loss_and_gradient,
    _refine_fft,
    _refine_torch,
    make_training_data,
    training_scenes,
)
from thintact_sdk.reconstruction.t2s import SystemMatrices

torch = pytest.importorskip("torch")


def _data():  # type: ignore[no-untyped-def]
    profile = load_profile("virtual-mini")
    sm = SystemMatrices.direct(profile, scale_dn=2400.0)
    n, m = sm.scene_shape
    return make_training_data(sm, training_scenes(n, m, 6, seed=1), noise=profile.noise, seed=0)


def test_the_written_out_gradient_is_autograds() -> None:
    data = _data()
    c, r, s = data.y.shape[1:]
    rng = np.random.default_rng(0)
    pf = (1.0 + 0.3 * rng.standard_normal((c, r, s))).astype(np.float32)
    ps = (1.0 + 0.3 * rng.standard_normal((c, r, s))).astype(np.float32)
    norm = float(np.sum(data.y_open.astype(np.float64) ** 2))
    loss, (gf, gs) = _loss_and_gradient([dct2(y) for y in data.y], data.y_open, pf, ps, norm)
    tr = SeparableDCT((r, s), (r, s), to_backend=lambda a: torch.from_numpy(a))
    tf = torch.tensor(pf, dtype=torch.float64, requires_grad=True)
    ts = torch.tensor(ps, dtype=torch.float64, requires_grad=True)
    y, yo = torch.from_numpy(data.y.astype(np.float64)), torch.from_numpy(data.y_open.astype(np.float64))
    ref = torch.sum((ts * tr.inv(tf * tr.fwd(y)) - yo) ** 2) / norm
    ref.backward()
    assert loss == pytest.approx(float(ref.detach()), rel=1e-5)
    for got, want in ((gf, tf.grad.numpy()), (gs, ts.grad.numpy())):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-4 * np.abs(want).max())


def test_fft_refinement_trains_as_well_as_the_torch_refinement() -> None:
    data = _data()
    r, s = data.y.shape[2:]
    phi_f, phi_s, hist = _closed_form(data, SeparableDCT((r, s)), None, 1)
    _, _, h_t = _refine_torch(data, None, phi_f, phi_s, None, 15, 0.01, None, min(hist))
    steps: list[int] = []
    f_n, s_n, h_n = _refine_fft(data, phi_f, phi_s, 15, 0.01, lambda k, _: steps.append(k), min(hist))
    assert steps == list(range(15))
    # the same first steps; later ones differ by float32 rounding, amplified by Adam's sign-like start
    np.testing.assert_allclose(h_n[:2], h_t[:2], rtol=1e-4)
    assert min(h_n) == pytest.approx(min(h_t), rel=0.05)
    assert f_n.shape == phi_f.shape and s_n.shape == phi_s.shape
    # a start that cannot be improved on is returned as it was
    f0, s0, _ = _refine_fft(data, phi_f, phi_s, 3, 0.01, None, 0.0)
    assert f0 is phi_f and s0 is phi_s
