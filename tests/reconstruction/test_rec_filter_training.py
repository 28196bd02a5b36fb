"""Joint-filter training: exact on frequency-split matrices, measured accuracy on a real geometry."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.reconstruction.filter_training import (
    make_training_data,
    train_joint_filter,
    training_scenes,
)
from thintact_sdk.reconstruction.synthetic_matrices import frequency_split_matrices
from thintact_sdk.reconstruction.t2s import SystemMatrices
from thintact_sdk.simulation.scenes import make_scene


def test_training_scenes_are_varied_and_in_range() -> None:
    scenes = training_scenes(20, 24, count=12, seed=3)
    assert len(scenes) == 12
    assert all(s.shape == (20, 24, 3) and s.min() >= 0 and s.max() <= 1 for s in scenes)
    for i in range(len(scenes)):
        for j in range(i):
            assert not np.allclose(scenes[i], scenes[j])


@pytest.mark.parametrize("kw", [{}, {"low_block": "auto", "phi_s_rank": 1}, {"steps": 10}])
def test_training_finds_the_exact_split(kw) -> None:
    sm, _ = frequency_split_matrices((48, 56), (16, 18), (6, 7), seed=2)
    jf = train_joint_filter(sm, training_scenes(16, 18, count=12), **({"steps": 0} | kw))
    assert jf.meta["final_loss"] < 1e-10
    x = make_scene("gelsight", 16, 18, 3)  # not in the training set
    np.testing.assert_allclose(jf.apply(sm.forward(x)), sm.forward_open(x),
                               atol=1e-5 * np.abs(sm.forward(x)).max())
    if kw.get("low_block") == "auto":
        assert jf.meta["low_block"] == [6, 7]
        assert np.all(jf.phi_f[:, 6:, :] == 0) and np.all(jf.phi_f[:, :, 7:] == 0)
        assert np.linalg.matrix_rank(jf.phi_s[0]) == 1


def test_filter_removes_the_open_component_of_the_virtual_mini_device() -> None:
    """Direct-generated matrices of virtual-mini: held-out scenes, measured accuracy.

    Measured (16 training scenes, 20 Adam steps): ‖F(Y) − Yo‖/‖Yo‖ = 0.25 % (white),
    1.0 % (USAF), 0.27 % (GelSight); relative to the coding component 2-6 %.
    """
    profile = load_profile("virtual-mini")
    sm = SystemMatrices.direct(profile, scale_dn=2400.0)
    n, m = sm.scene_shape
    jf = train_joint_filter(sm, training_scenes(n, m, 16, seed=1), steps=20, low_block="auto",
                            phi_s_rank=2)
    assert jf.meta["final_loss"] <= min(jf.meta["closed_form_loss"])
    for name, index in (("white", 0), ("usaf", 0), ("gelsight", 9)):
        x = make_scene(name, n, m, index)
        y, yo = sm.forward(x), sm.forward_open(x)
        err = np.linalg.norm(jf.apply(y) - yo)
        assert err / np.linalg.norm(yo) < 0.02, name
        assert err / np.linalg.norm(y - yo) < 0.1, name
        # far better than not filtering at all, or than taking the DC alone
        assert err < 0.05 * np.linalg.norm(yo)


def test_noisy_training_data_has_the_sensor_variance() -> None:
    profile = load_profile("virtual-mini")
    sm, _ = frequency_split_matrices((48, 56), (16, 18), (6, 7), seed=2, gain_dn=2000.0)
    scenes = [np.full((16, 18, 3), 0.5, np.float32)] * 4
    clean = make_training_data(sm, scenes)
    noisy = make_training_data(sm, scenes, noise=profile.noise, seed=1)
    resid = (noisy.y - clean.y).astype(np.float64)
    expected = profile.noise.read_noise_dn**2 + np.maximum(clean.y, 0) / profile.noise.electrons_per_dn
    assert np.mean(resid**2 / expected) == pytest.approx(1.0, rel=0.1)


def test_training_its_own_data_spends_the_measurements_for_their_spectra() -> None:
    """With no data passed and no gradient steps, the measurements become their spectra in
    place (issue 36: 0.5 GB less at the paper's size): the same filter as from the same data
    passed in, which is left untouched, and one data set's bytes less at the peak."""
    import tracemalloc

    from thintact_sdk.formats.profiles import NoiseSpec

    sm, _ = frequency_split_matrices((64, 72), (16, 18), (6, 7), seed=4)
    scenes = training_scenes(16, 18, count=10, seed=1)
    noise = NoiseSpec(black_level_dn=0.0, read_noise_dn=2.0, electrons_per_dn=4.0, saturation_dn=4095.0)
    data = make_training_data(sm, scenes, noise=noise, seed=0)
    kept = data.y.copy()
    tracemalloc.start()
    given = train_joint_filter(sm, data=data, steps=0, seed=0)
    peak_given = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    np.testing.assert_array_equal(data.y, kept)
    tracemalloc.start()
    own = train_joint_filter(sm, scenes, noise=noise, steps=0, seed=0)
    peak_own = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    np.testing.assert_array_equal(own.phi_f, given.phi_f)
    np.testing.assert_array_equal(own.phi_s, given.phi_s)
    assert own.meta["closed_form_loss"] == given.meta["closed_form_loss"]
    # making the data set costs its measurements alone (the open components are computed
    # when read, not held), and the spectra are not added beside them
    assert peak_own - peak_given < 0.5 * data.y.nbytes, (peak_own, peak_given, data.y.nbytes)


def test_open_components_computed_when_read_equal_the_held_ones() -> None:
    """``hold_open=False`` gives the same measurements (same noise stream) and open components
    equal to the held ones, bit for bit; a matrices set without open term reads as none."""
    from thintact_sdk.formats.profiles import NoiseSpec
    from thintact_sdk.reconstruction.filter_training import OpenComponents

    sm, _ = frequency_split_matrices((40, 48), (12, 14), (5, 6), seed=7)
    scenes = training_scenes(12, 14, count=5, seed=2)
    noise = NoiseSpec(black_level_dn=0.0, read_noise_dn=2.0, electrons_per_dn=4.0, saturation_dn=4095.0)
    held = make_training_data(sm, scenes, noise=noise, seed=3)
    lazy = make_training_data(sm, scenes, noise=noise, seed=3, hold_open=False)
    assert isinstance(lazy.y_open, OpenComponents) and lazy.y_open.shape == held.y_open.shape
    np.testing.assert_array_equal(lazy.y, held.y)
    for f, yo in enumerate(lazy.y_open):
        assert yo.dtype == np.float32
        np.testing.assert_array_equal(yo, held.y_open[f])
    np.testing.assert_array_equal(np.asarray(lazy.y_open), held.y_open)
    assert lazy.has_open() and held.has_open()
    coding_only = SystemMatrices(sm.Po * 0, sm.Qo, sm.Pc, sm.Qc, {})
    assert not make_training_data(coding_only, scenes, hold_open=False).has_open()
    jf = train_joint_filter(coding_only, scenes, steps=0)
    assert jf.meta["method"].startswith("none")
