"""SystemMatrices, nearest-Kronecker fit, joint filter and calibration bundle persistence."""

from __future__ import annotations

import json

import numpy as np
import pytest

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.reconstruction.bundle import CalibrationBundle, find_latest
from thintact_sdk.reconstruction.kron import nearest_kron
from thintact_sdk.reconstruction.synthetic_matrices import frequency_split_matrices
from thintact_sdk.reconstruction.t2s import SystemMatrices, kron_sum_norm2


def _random_sm(seed: int = 0) -> SystemMatrices:
    rng = np.random.default_rng(seed)
    return SystemMatrices(
        rng.random((3, 12, 5)), rng.random((3, 14, 6)), rng.standard_normal((3, 12, 5)),
        rng.standard_normal((3, 14, 6)), {"note": "random"},
    )


def test_forward_is_sum_of_two_separable_terms() -> None:
    sm = _random_sm()
    x = np.random.default_rng(1).random((5, 6, 3))
    y = sm.forward(x)
    assert y.shape == (12, 14, 3)
    for c in range(3):
        po, qo, pc, qc = sm.channel(c)
        np.testing.assert_allclose(y[..., c], po @ x[..., c] @ qo.T + pc @ x[..., c] @ qc.T)
    # linear in the scene, and the kron form agrees with the matrix form
    vec = np.kron(sm.Qo[0], sm.Po[0]) @ x[..., 0].ravel(order="F")
    np.testing.assert_allclose(sm.forward_open(x)[..., 0].ravel(order="F"), vec)


def test_shape_errors_are_calibration_errors() -> None:
    with pytest.raises(CalibrationError, match="differ in shape"):
        SystemMatrices(np.ones((1, 4, 3)), np.ones((1, 5, 2)), np.ones((1, 4, 2)), np.ones((1, 5, 2)))
    with pytest.raises(ValueError, match="scene must be"):
        _random_sm().forward(np.ones((4, 6, 3)))


def test_save_load_roundtrip_keeps_metadata(tmp_path) -> None:
    sm = _random_sm()
    p = sm.save(tmp_path / "sm.npz")
    back = SystemMatrices.load(p)
    assert back.meta == {"note": "random"}
    np.testing.assert_allclose(back.Pc, sm.Pc, rtol=1e-6)
    assert back.Po.dtype == np.float32
    assert back.relative_error(sm) < 1e-6
    with pytest.raises(CalibrationError, match="not found"):
        SystemMatrices.load(tmp_path / "missing.npz")


def test_kron_norm_matches_dense_operator() -> None:
    rng = np.random.default_rng(2)
    terms = [(rng.standard_normal(), rng.random((4, 3)), rng.random((5, 2))) for _ in range(3)]
    dense = sum(w * np.kron(q, p) for w, p, q in terms)
    assert kron_sum_norm2(terms) == pytest.approx(np.sum(dense**2), rel=1e-10)


def test_nearest_kron_is_the_best_rank_one_rearrangement() -> None:
    rng = np.random.default_rng(3)
    terms = [(rng.random((6, 4)), rng.random((7, 5))) for _ in range(4)]
    p, q = nearest_kron(terms)
    dense = sum(np.kron(qk, pk) for pk, qk in terms)
    # Van Loan: rearrange A so that Q⊗P ↔ vec(Q) vec(P)ᵀ; best rank-1 via dense SVD
    rows = []
    for i in range(7):
        for j in range(5):
            rows.append(dense[i * 6 : (i + 1) * 6, j * 4 : (j + 1) * 4].ravel(order="F"))
    rmat = np.array(rows)  # (S·M) × (R·N), row = block (i, j) ↔ Q[i, j]
    sv = np.linalg.svd(rmat, compute_uv=False)
    best_err2 = np.sum(sv[1:] ** 2)
    got_err2 = np.sum((dense - np.kron(q, p)) ** 2)
    assert got_err2 == pytest.approx(best_err2, rel=1e-8, abs=1e-10)
    # exact for a single term
    p1, q1 = nearest_kron(terms[:1])
    np.testing.assert_allclose(np.kron(q1, p1), np.kron(terms[0][1], terms[0][0]), atol=1e-10)


def test_joint_filter_roundtrip_and_exact_split(tmp_path) -> None:
    sm, jf = frequency_split_matrices((40, 44), (12, 14), (6, 7), seed=4)
    x = np.random.default_rng(5).random((12, 14, 3))
    y = sm.forward(x)
    np.testing.assert_allclose(jf.apply(y), sm.forward_open(x), atol=1e-9 * np.abs(y).max())
    back = type(jf).load(jf.save(tmp_path / "filter.npz"))
    np.testing.assert_array_equal(back.phi_f, jf.phi_f.astype(np.float32))


def test_bundle_save_load_and_find_latest(tmp_path) -> None:
    profile = load_profile("virtual-mini")
    sm, jf = frequency_split_matrices((40, 44), (12, 14), (6, 7), seed=4)
    bundle = CalibrationBundle.create(
        profile, sm, jf, tau=1e-3, source="simulator", exposure_us=10000, metrics={"psnr_db": 30.0}
    )
    dev = tmp_path / "virtual-mini"
    bundle.save(dev / "20260101T000000")
    bundle.save(dev / "20260102T000000")
    (dev / "20260103T000000").mkdir()  # not a bundle: ignored
    latest = find_latest(dev)
    assert latest.name == "20260102T000000"
    loaded = CalibrationBundle.load(latest)
    meta = json.loads((latest / "calibration.json").read_text())
    for key in ("format", "profile", "profile_hash", "software_version", "created", "tau",
                "exposure_us", "metrics", "source"):
        assert key in meta
    assert meta["format"] == "thintact-calibration/1"
    assert loaded.tau == 1e-3 and loaded.matches_profile(profile)
    assert loaded.filter is not None and loaded.filter.channels == 3
    with pytest.raises(CalibrationError, match="sensor"):
        loaded.check_shapes(profile)
    with pytest.raises(CalibrationError, match="no calibration bundle"):
        find_latest(tmp_path / "nothing")
    with pytest.raises(CalibrationError, match="source must be"):
        CalibrationBundle.create(profile, sm, jf, tau=1.0, source="guess")


class _FakeSimulator:
    """Stands in for Simulator: open/coding terms with a known best two-term fit."""

    def __init__(self, exact: bool) -> None:
        rng = np.random.default_rng(7)
        self.profile = None
        self.po, self.qo = rng.random((9, 4)), rng.random((10, 5))
        self.pc, self.qc = rng.standard_normal((9, 4)), rng.standard_normal((10, 5))
        self.extra = None if exact else (0.01 * rng.random((9, 4)), rng.random((10, 5)))

    def open_coding_terms(self, channel: int):
        open_terms = [(self.po, self.qo)] + ([self.extra] if self.extra else [])
        return open_terms, [(self.pc, self.qc)]


def test_two_term_fit_is_exact_for_two_separable_terms_and_reports_its_error() -> None:
    sm = SystemMatrices.two_term_fit(_FakeSimulator(exact=True), scale_dn=4.0, channels=[0, 1])
    assert sm.channels == 2 and max(sm.meta["fit_relative_error"]) < 1e-7
    x = np.random.default_rng(8).random((4, 5, 2))
    want = 4.0 * (np.einsum("rn,nmc,sm->rsc", _FakeSimulator(True).po, x, _FakeSimulator(True).qo)
                  + np.einsum("rn,nmc,sm->rsc", _FakeSimulator(True).pc, x, _FakeSimulator(True).qc))
    np.testing.assert_allclose(sm.forward(x), want, rtol=1e-9)
    approx = SystemMatrices.two_term_fit(_FakeSimulator(exact=False), channels=[0])
    assert 1e-4 < approx.meta["fit_relative_error"][0] < 0.05


def test_direct_generation_shapes_and_scale() -> None:
    profile = load_profile("virtual-mini")
    one = SystemMatrices.direct(profile)
    two = SystemMatrices.direct(profile, scale_dn=4.0)
    assert one.Po.shape == (3, 128, 50) and one.Qc.shape == (3, 160, 64)
    x = np.ones((50, 64, 3))
    np.testing.assert_allclose(two.forward(x), 4.0 * one.forward(x), rtol=1e-9)
    assert two.meta["source"] == "direct" and two.meta["profile_hash"] == profile.content_hash()
