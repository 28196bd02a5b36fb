"""Judging a real unit: τ from its own frames, validation against its design's prediction,
health with located defects, on recordings made without the decoder's assumptions."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from independent_device import (
    DimColumn,
    Dust,
    Ghost,
    best_in_hindsight,
    mean_psnr,
    small_profile,
    write_recording,
)

from thintact_sdk.apps.cli.main import main
from thintact_sdk.calibration.collect import collect_slits, signal_of
from thintact_sdk.calibration.pipeline import CalibrationOptions, solve_matrices
from thintact_sdk.calibration.tau import (
    assign_folds,
    bootstrap_spread,
    cross_validate,
    cross_validate_prior,
)
from thintact_sdk.calibration.validation import make_decoder
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.recording import Recording, RecordingWriter
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.metrics import psnr
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices
from thintact_sdk.simulation.scenes import gelsight


class _ScaledDecoder:
    """Linear stand-in decoder: ``decode(y) = y / (1 + τ)`` on a 1×1 grid."""

    def __init__(self) -> None:
        self.tau = 0.0

    def set_tau(self, tau: float) -> None:
        self.tau = tau

    def decode(self, y: np.ndarray) -> np.ndarray:
        return np.asarray(y, np.float32) / (1.0 + self.tau)


def test_cross_validation_never_scores_a_scene_with_a_tau_tuned_on_it() -> None:
    # fold 0 (truths ≈ 0.5 from 1.0) wants τ = 1; fold 1 (truths ≈ 0.25) wants τ = 3
    values = [0.5, 0.25, 0.49, 0.26, 0.5]
    truths = [np.full((1, 1, 1), v) for v in values]
    signals = [np.ones((1, 1, 1), np.float32)] * len(values)
    folds = assign_folds(truths)
    assert folds == [0, 1, 0, 1, 0]  # identical scenes (the first and the last) share a fold
    labels = ["a", "b", "c", "d", "a2"]
    cv = cross_validate(_ScaledDecoder(), "stub", signals, truths, labels, np.array([1.0, 3.0]))
    assert cv is not None
    assert cv.fold_tau == [1.0, 3.0]
    # each scene is scored with the other fold's τ: perfect in its own fold, not held out
    assert cv.held_out_psnr["a"] == pytest.approx(psnr(np.full((1, 1, 1), 0.25), truths[0]))
    assert cv.held_out_psnr["b"] == pytest.approx(psnr(np.full((1, 1, 1), 0.5), truths[1]))
    # one distinct scene per fold is too few to tune on
    assert cross_validate(_ScaledDecoder(), "stub", signals[:2], truths[:2], labels[:2], np.array([1.0])) is None


class _PriorDecoder:
    """Stand-in decoder of one prior on a 1×1 grid: ``decode(y) = s·y / (1 + τ)`` with
    ``s = 0.05`` for plain Tikhonov and ``SCALE[p]`` for prior ``p``."""

    SCALE = {ScenePrior(1.0, 8.0): 1.2, ScenePrior(0.5, 8.0): 0.3}

    def __init__(self, prior: ScenePrior | None, scale: dict[ScenePrior, float] | None = None) -> None:
        self.prior, self.tau = prior, 1.0
        self.scale = self.SCALE if scale is None else scale

    def set_tau(self, tau: float) -> None:
        self.tau = tau

    def decode(self, y: np.ndarray) -> np.ndarray:
        s = 0.05 if self.prior is None else self.scale[self.prior]
        return np.asarray(y, np.float32) * s / (1.0 + self.tau)


def test_prior_cross_validation_never_scores_a_scene_with_a_tau_tuned_on_it() -> None:
    # fold 0 (truths ≈ 0.6) wants τ = 1 with the first prior, fold 1 (≈ 0.4) τ = 2; plain is poor
    values = [0.605, 0.41, 0.61, 0.39, 0.59]
    truths = [np.full((1, 1, 1), v) for v in values]
    signals = [np.ones((1, 1, 1), np.float32)] * len(values)
    labels = ["a", "b", "c", "d", "e"]
    taus = np.array([1.0, 2.0])
    p1, p2 = list(_PriorDecoder.SCALE)
    cv = cross_validate_prior(_PriorDecoder, "stub", signals, truths, labels, taus, [p1, p2])
    assert cv is not None and cv.folds == [0, 1, 0, 1, 0]
    # every candidate is cross-validated over τ on its own, the best held out is deployed
    alone = {p: cross_validate(_PriorDecoder(p), "stub", signals, truths, labels, taus) for p in (None, p1, p2)}
    assert cv.prior_held_out_db == {p: alone[p].held_out_mean_db for p in (p1, p2)}  # type: ignore[union-attr]
    best = max(alone, key=lambda p: alone[p].held_out_mean_db)  # type: ignore[union-attr]
    assert cv.prior == best == p1 and cv.fold_prior == [p1, p1]
    assert cv.held_out_mean_db > cv.plain_held_out_db == alone[None].held_out_mean_db  # type: ignore[union-attr]
    # each scene is scored with the τ tuned on the other fold: 0.4 for fold 0, 0.6 for fold 1
    assert cv.fold_tau == [1.0, 2.0]
    for label, x, fold in zip(labels, values, cv.folds, strict=True):
        other = 0.4 if fold == 0 else 0.6
        assert cv.held_out_psnr[label] == pytest.approx(psnr(np.full((1, 1, 1), other), np.full((1, 1, 1), x)))
    # priors that score worse held out than plain Tikhonov are not deployed
    bad = {p1: 0.01, p2: 0.02}
    plain_only = cross_validate_prior(lambda p: _PriorDecoder(p, bad), "stub", signals, truths, labels, taus,
                                      [p1, p2])
    assert plain_only is not None and plain_only.prior is None and "not used" in plain_only.curve.note
    assert plain_only.fold_tau == alone[None].fold_tau  # type: ignore[union-attr]


def test_a_prior_that_wins_the_mean_on_one_scene_only_is_not_deployed() -> None:
    # the prior's estimate is far too bright (clipped to 1): a perfect white scene, ∞ dB, wins the
    # mean; plain Tikhonov (0.6 / (1 + τ) ≈ 0.3) is far better on the four other scenes
    values = [1.0, 0.305, 0.31, 0.295, 0.315]
    truths = [np.full((1, 1, 1), v) for v in values]
    signals = [np.ones((1, 1, 1), np.float32)] * len(values)
    labels = ["white", "b", "c", "d", "e"]
    prior = ScenePrior(1.5, 4.0)
    scales = {None: 0.6, prior: 10.0}

    class _Decoder(_PriorDecoder):
        def decode(self, y: np.ndarray) -> np.ndarray:
            return np.asarray(y, np.float32) * scales[self.prior] / (1.0 + self.tau)

    taus = np.array([1.0, 2.0])
    alone = cross_validate(_Decoder(prior), "stub", signals, truths, labels, taus)
    assert alone is not None and alone.held_out_psnr["white"] == np.inf
    assert alone.held_out_mean_db > cross_validate(_Decoder(None), "stub", signals, truths, labels,  # type: ignore[union-attr]
                                                   taus).held_out_mean_db
    cv = cross_validate_prior(_Decoder, "stub", signals, truths, labels, taus, [prior])
    assert cv is not None and cv.prior is None and "median scene" in cv.curve.note


def test_bootstrap_spread_says_how_well_the_scenes_determine_tau() -> None:
    taus = np.geomspace(1.0, 1e4, 41)
    lt = np.log10(taus)

    def curve(best: float) -> np.ndarray:  # a scene whose PSNR peaks at τ = 10**best
        return 30.0 - (lt - best) ** 2

    agree = np.stack([curve(2.0) for _ in range(5)])
    keys = [f"s{i}" for i in range(5)]
    lo, hi = bootstrap_spread(taus, agree, keys, np.ones(5))
    assert lo == pytest.approx(100.0) and hi == pytest.approx(100.0)
    # scenes wanting 10 and 1000: the resamples' choices spread between them
    split = np.stack([curve(1.0), curve(3.0), curve(1.0), curve(3.0), curve(2.0), curve(2.0)])
    keys = ["a", "b", "c", "d", "e", "e"]  # the last two rows are one scene, counted once
    lo, hi = bootstrap_spread(taus, split, keys, np.array([1, 1, 1, 1, 0.5, 0.5]))
    assert 10.0 < lo < 100.0 < hi < 1000.0
    assert np.isnan(bootstrap_spread(taus, split[:2], ["a", "b"], np.ones(2))[0])  # too few scenes


def _test_scenes(n: int, m: int) -> list[tuple[str, np.ndarray]]:
    """Scenes the calibration never saw (other presses, a smooth random field)."""
    rng = np.random.default_rng(7)
    from scipy.ndimage import gaussian_filter

    field = gaussian_filter(rng.random((n, m, 3)), (3, 3, 0))
    field = (field - field.min()) / np.ptp(field)
    return [(f"test_gelsight_{i}", gelsight(n, m, i)) for i in range(3, 6)] + [("test_field", field)]


@pytest.fixture(scope="module")
def healthy(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """A healthy RGB unit: calibration recording, its bundle (via the CLI), a test recording."""
    root = tmp_path_factory.mktemp("healthy")
    profile = small_profile(("R", "G", "B"))
    write_recording(root / "rec", profile, seed=1)
    rc = main(["calibrate", "--from-recording", str(root / "rec"), "--out", str(root / "cal"),
               "--filter-steps", "10", "--no-progress"])
    assert rc == 0, (root / "cal" / "calibration.json").read_text()
    # the same unit (same true physics), new scenes, one capture each
    from independent_device import TRUE_PHYSICS

    from thintact_sdk.simulation.noise import signal_to_dn
    from thintact_sdk.simulation.simulator import Simulator

    sim = Simulator(profile.with_physics(TRUE_PHYSICS))
    nz = profile.noise
    n, m = profile.scene.rows, profile.scene.cols
    gain = 0.7 * (nz.saturation_dn - nz.black_level_dn) / float(np.max(sim.linear_batch(np.ones((1, n, m, 3)))))
    rng = np.random.default_rng(99)
    w = RecordingWriter(root / "test", profile)
    w.add(signal_to_dn(np.zeros((64, 80, 3)), nz, rng).astype(np.uint16), np.zeros((n, m, 3), np.float32),
          label="dark")
    for label, x in _test_scenes(n, m):
        w.add(signal_to_dn(sim.predict_signal_dn(x, gain), nz, rng).astype(np.uint16), x.astype(np.float32),
              label=label)
    return root / "rec", root / "cal", root / "test"


def test_healthy_unit_passes_against_its_own_prediction(healthy: tuple[Path, Path, Path]) -> None:
    _, cal, _ = healthy
    meta = json.loads((cal / "calibration.json").read_text())
    m = meta["metrics"]
    assert m["passed"] and m["verdict"]["failures"] == []
    assert m["health"]["defects"] == []
    assert all(s["shortfall_db"] <= 1.5 for s in m["verdict"]["scenes"])
    criteria = {c["criterion"] for c in m["tau_selection"]["curves"]}
    assert {"gcv", "discrepancy", "simulated"} <= criteria
    assert any(c.startswith("cross-validation") for c in criteria)
    assert meta["decoder"] == m["tau_selection"]["decoder"]
    report = (cal / "report.html").read_text()
    assert "Health" in report and "predicted PSNR" in report and "below limit" not in report
    assert "τ per channel" in report and "per_channel_check" in m["tau_selection"]
    # the scene-prior criterion: every candidate's held-out mean in the report and the json
    assert "Scene prior for" in report and "held-out mean PSNR (dB)" in report
    assert len(m["tau_selection"]["scene_prior_candidates"]["t2s-closed-form"]) == 9
    assert not re.search(r"\d\.\d{9,}", report.split("<img")[0])  # no raw 15-digit floats


def test_default_reconstruct_is_near_the_best_tau_and_beats_the_paper_pipeline(
        healthy: tuple[Path, Path, Path], tmp_path: Path) -> None:
    rec_dir, cal, test_dir = healthy
    test = Recording(test_dir)
    assert main(["reconstruct", str(test_dir), "--calibration", str(cal), "--out", str(tmp_path / "d"),
                 "--no-progress"]) == 0
    default = mean_psnr(tmp_path / "d", test)
    bundle = CalibrationBundle.load(cal)
    profile = test.profile
    dark = np.asarray(test.measurement(0), np.float64)
    frames = [(signal_of(test, i, dark, None)[0].astype(np.float32), np.asarray(test.scene(i)))
              for i in range(1, len(test))]
    hindsight, _ = best_in_hindsight(make_decoder(profile, bundle, bundle.meta["decoder"]), frames)
    rec = Recording(rec_dir)
    paper_sm, _ = solve_matrices(collect_slits(rec), CalibrationOptions(method="paper"), profile)
    paper = CalibrationBundle.create(profile, paper_sm, None, tau=1.0, source="recording")
    reference, _ = best_in_hindsight(make_decoder(profile, paper, "t2s-closed-form"), frames)
    print(f"default {default:.2f} dB, hindsight {hindsight:.2f} dB, Alg. 1-3 + exact T2S {reference:.2f} dB")
    assert default >= hindsight - 0.3
    assert default >= reference - 0.05


@pytest.fixture(scope="module")
def defective(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, Path]:
    root = tmp_path_factory.mktemp("defective")
    write_recording(root / "rec", small_profile(("mono",)), seed=2,
                    defects=[Dust(row=20, col=50), DimColumn(col=33)])
    rc = main(["calibrate", "--from-recording", str(root / "rec"), "--out", str(root / "cal"),
               "--filter-steps", "0", "--no-progress"])
    return rc, root / "cal"


def test_defective_unit_fails_naming_and_locating_each_defect(defective: tuple[int, Path]) -> None:
    rc, cal = defective
    assert rc == 1
    m = json.loads((cal / "calibration.json").read_text())["metrics"]
    defects = {d["kind"]: d for d in m["health"]["defects"]}
    assert set(defects) == {"dust speck", "dim column"}
    assert abs(defects["dust speck"]["centre"][0] - 20) <= 1.5 and abs(defects["dust speck"]["centre"][1] - 50) <= 1.5
    assert defects["dim column"]["col0"] == 33 and defects["dim column"]["strength"] == pytest.approx(-0.15, abs=0.02)
    whats = [f["what"] for f in m["verdict"]["failures"]]
    assert "dust speck" in whats and "dim column" in whats
    report = (cal / "report.html").read_text()
    assert "Suggested fix" in report and "dust speck at sensor rows" in report
    assert "ghost" not in {d["kind"] for d in m["health"]["defects"]}


class _ChannelScaledDecoder:
    """Linear stand-in decoder per channel: ``decode(y)[..., c] = y[..., c] / (1 + τ_c)``."""

    def __init__(self) -> None:
        self.tau = np.ones(3)

    def set_tau(self, tau: object) -> None:
        self.tau = np.broadcast_to(np.asarray(tau, np.float64), (3,)).copy()

    def decode(self, y: np.ndarray) -> np.ndarray:
        return np.asarray(y, np.float32) / (1.0 + self.tau).astype(np.float32)


@pytest.mark.parametrize("wanted", [(1.0, 3.0, 1.0), (1.0, 1.0, 1.0)])
def test_tau_per_channel_only_where_it_scores_better_held_out(wanted: tuple[float, float, float]) -> None:
    # channel c of every scene is best reconstructed at τ_c = wanted[c] (up to a small
    # scene-to-scene spread); a τ per channel must be kept only when the channels differ
    rng = np.random.default_rng(0)
    truths = [np.array([[[1 / (1 + t + 0.05 * rng.standard_normal()) for t in wanted]]]) for _ in range(6)]
    signals = [np.ones((1, 1, 3), np.float32)] * 6
    grid = np.array([0.5, 1.0, 1.5, 2.0, 3.0, 4.0])
    cv = cross_validate(_ChannelScaledDecoder(), "stub", signals, truths, [f"s{i}" for i in range(6)], grid)
    assert cv is not None and len(cv.channel_fold_tau) == 6  # one tuning per left-out scene
    if wanted[1] != wanted[0]:
        assert cv.channel_tau is not None and cv.channel_tau[1] > 2 * cv.channel_tau[0]
        assert cv.held_out_channel_db > cv.held_out_shared_db + cv.channel_gain_se_db
    else:
        assert cv.channel_tau is None


def _random_matrices(profile: Profile, seed: int) -> SystemMatrices:
    """Random three-channel T2S matrices of ``profile``'s shapes (positive coding terms)."""
    rng = np.random.default_rng(seed)
    (r, s), (n, m) = (profile.sensor.rows, profile.sensor.cols), (profile.scene.rows, profile.scene.cols)
    return SystemMatrices(np.abs(rng.random((3, r, n))), np.abs(rng.random((3, s, m))),
                          rng.standard_normal((3, r, n)), rng.standard_normal((3, s, m)))


def test_bundle_tau_per_channel_is_used_unless_tau_is_given(tmp_path: Path) -> None:
    profile = small_profile(("R", "G", "B"))
    sm = _random_matrices(profile, seed=3)
    per_channel = [10.0, 200.0, 50.0]
    CalibrationBundle.create(profile, sm, None, tau=7.0, source="recording", decoder="t2s-closed-form",
                             tau_t2s_closed_form=80.0,
                             channel_tau={"t2s-closed-form": per_channel}).save(tmp_path / "cal")
    bundle = CalibrationBundle.load(tmp_path / "cal")
    assert list(make_decoder(profile, bundle, "t2s-closed-form").channel_tau) == per_channel  # type: ignore[attr-defined]
    assert list(make_decoder(profile, bundle, "t2s-closed-form", tau=5.0).channel_tau) == [5.0] * 3  # type: ignore[attr-defined]
    # a decoder without a τ per channel in the bundle keeps its own single τ
    assert make_decoder(profile, bundle, "t2s-iterative").tau == 7.0  # type: ignore[attr-defined]
    # and a malformed field is refused naming it
    meta = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    meta["channel_tau"] = {"t2s-closed-form": [10.0, -1.0, 5.0]}
    (tmp_path / "cal" / "calibration.json").write_text(json.dumps(meta))
    from thintact_sdk.errors import CalibrationError

    with pytest.raises(CalibrationError, match="channel_tau"):
        CalibrationBundle.load(tmp_path / "cal")


def test_bundle_scene_prior_is_used_unless_tau_is_given_and_old_bundles_decode_as_before(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from dataclasses import replace

    import thintact_sdk.reconstruction.decoders.components as thintact_decoders
    from thintact_sdk.errors import CalibrationError
    from thintact_sdk.host.machine import host_capabilities
    from thintact_sdk.reconstruction.decoders import ArrayBackend, T2SClosedFormDecoder

    # the decoders are compared with float32 solves to 1e-4: on a host with native bfloat16
    # the measured-fastest backend may be torch-bfloat16 (~1e-2 off), so it is not a candidate
    monkeypatch.setattr(thintact_decoders, "host_capabilities",
                        lambda: replace(host_capabilities(), native_bf16=False))

    profile = small_profile(("R", "G", "B"))
    sm = _random_matrices(profile, seed=6)
    prior = ScenePrior(1.0, 8.0)
    y = sm.forward(gelsight(profile.scene.rows, profile.scene.cols, 0)).astype(np.float32)
    # an old bundle (no scene_prior): plain Tikhonov at its τ, as before
    CalibrationBundle.create(profile, sm, None, tau=7.0, source="recording", decoder="t2s-closed-form",
                             tau_t2s_closed_form=80.0).save(tmp_path / "old")
    old = make_decoder(profile, CalibrationBundle.load(tmp_path / "old"), "t2s-closed-form")
    assert old.prior is None  # type: ignore[attr-defined]
    plain = T2SClosedFormDecoder(sm, 80.0, ArrayBackend("numpy")).decode(y)
    np.testing.assert_allclose(old.decode(y), plain, rtol=1e-4, atol=1e-4)
    # a bundle with a scene prior: generalised Tikhonov at its τ; tau in the settings (--tau) is plain
    CalibrationBundle.create(profile, sm, None, tau=7.0, source="recording", decoder="t2s-closed-form",
                             tau_t2s_closed_form=80.0,
                             scene_prior={"t2s-closed-form": prior.to_json()}).save(tmp_path / "new")
    bundle = CalibrationBundle.load(tmp_path / "new")
    new = make_decoder(profile, bundle, "t2s-closed-form")
    assert new.prior == prior  # type: ignore[attr-defined]
    generalised = T2SClosedFormDecoder(sm, 80.0, ArrayBackend("numpy"), prior=prior).decode(y)
    np.testing.assert_allclose(new.decode(y), generalised, rtol=1e-4, atol=1e-4)
    assert not np.allclose(generalised, plain, atol=1e-3)
    overridden = make_decoder(profile, bundle, "t2s-closed-form", tau=80.0)
    assert overridden.prior is None  # type: ignore[attr-defined]
    np.testing.assert_allclose(overridden.decode(y), plain, rtol=1e-4, atol=1e-4)
    # a malformed prior is refused naming the field
    meta = json.loads((tmp_path / "new" / "calibration.json").read_text())
    meta["scene_prior"] = {"t2s-closed-form": {"kind": "dct-power", "alpha": -1.0, "k0": 8.0}}
    (tmp_path / "new" / "calibration.json").write_text(json.dumps(meta))
    with pytest.raises(CalibrationError, match="scene_prior"):
        CalibrationBundle.load(tmp_path / "new")


@pytest.fixture(scope="module", params=[Ghost(6, -9, 0.08), Ghost(0, 11, 0.08)], ids=["diagonal", "separable"])
def ghosted(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[Ghost, int, Path]:
    ghost: Ghost = request.param
    root = tmp_path_factory.mktemp("ghost")
    write_recording(root / "rec", small_profile(("mono",)), seed=4, defects=[ghost])
    rc = main(["calibrate", "--from-recording", str(root / "rec"), "--out", str(root / "cal"),
               "--filter-steps", "0", "--no-progress"])
    return ghost, rc, root / "cal"


def test_a_ghost_fails_the_unit_with_its_offset_and_strength(ghosted: tuple[Ghost, int, Path]) -> None:
    # a diagonal ghost cannot be separable and raises the slit residuals; one along an axis
    # is absorbed exactly by the two-term matrices and shows only as an echo of the design
    ghost, rc, cal = ghosted
    assert rc == 1
    m = json.loads((cal / "calibration.json").read_text())["metrics"]
    ghosts = m["health"]["defects"]
    assert [d["kind"] for d in ghosts] == ["ghost"]  # its edge band is not taken for dust
    assert ghosts[0]["offset_px"] == [ghost.rows, ghost.cols]
    assert ghosts[0]["strength"] == pytest.approx(ghost.strength, abs=0.02)
    assert "ghost" in [f["what"] for f in m["verdict"]["failures"]]
    report = (cal / "report.html").read_text()
    assert f"displaced by {ghost.rows:+d} rows, {ghost.cols:+d} columns" in report and "Ghost search" in report


def test_reconstruct_uses_the_bundles_tau_per_channel_unless_tau_is_given(tmp_path: Path) -> None:
    profile = small_profile(("R", "G", "B"))
    sm = _random_matrices(profile, seed=5)
    (r, s), (n, m) = (profile.sensor.rows, profile.sensor.cols), (profile.scene.rows, profile.scene.cols)
    CalibrationBundle.create(profile, sm, None, tau=7.0, source="recording", decoder="t2s-closed-form",
                             tau_t2s_closed_form=80.0,
                             channel_tau={"t2s-closed-form": [10.0, 2000.0, 50.0]}).save(tmp_path / "cal")
    bundle = CalibrationBundle.load(tmp_path / "cal")
    black = 100.0
    scene = gelsight(n, m, 0)
    y = np.rint(sm.forward(scene) + black).astype(np.uint16)
    w = RecordingWriter(tmp_path / "rec", profile)
    w.add(np.full((r, s, 3), black, np.uint16), np.zeros((n, m, 3), np.float32), label="dark")
    w.add(y, scene.astype(np.float32), label="press")
    signal = y.astype(np.float32) - black
    for extra, settings in (([], {}), (["--tau", "5"], {"tau": 5.0})):
        out = tmp_path / f"out{len(extra)}"
        assert main(["reconstruct", str(tmp_path / "rec"), "--calibration", str(tmp_path / "cal"),
                     "--out", str(out), "--no-progress", *extra]) == 0
        got = np.load(out / "001_press.npy")
        expected = make_decoder(profile, bundle, "t2s-closed-form", **settings).decode(signal)
        np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-4)
    # the bundle's τ per channel and --tau give different reconstructions
    assert not np.allclose(np.load(tmp_path / "out0" / "001_press.npy"),
                           np.load(tmp_path / "out2" / "001_press.npy"), atol=1e-3)
