"""Direct generation of Po, Qo, Pc, Qc from φ: shapes, slopes, fade, normalisation, physics."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from thintact_sdk.formats.profiles import Profile, profile_from_dict, read_profile_file
from thintact_sdk.reconstruction.direct_generation import (
    SIGMOID_SOFTNESS,
    AxisGeometry,
    DirectGenerator,
    direct_system_matrices,
)


def make_profile(rows: int = 24, cols: int = 30, n: int = 10, m: int = 12, K: int = 40,  # noqa: N803
                 pitch_um: float = 40.0, scene_pitch_um: float = 126.0,
                 feature_um: float = 60.0) -> Profile:
    """A small device with the paper's distances (z = 4.8 mm, d = 1 mm); the masks plugin's
    tests use the same one (plugins/thintact_masks/tests/mask_profiles.py)."""
    return profile_from_dict({
        "format": "thintact-profile/1", "name": "mask-tiny",
        "sensor": {"rows": rows, "cols": cols, "pixel_pitch_um": pitch_um},
        "scene": {"rows": n, "cols": m, "pixel_pitch_um": scene_pitch_um},
        "mask": {"feature_um": feature_um, "phi": [1 if i % 3 else -1 for i in range(K)]},
        "geometry": {"scene_to_mask_mm": 4.8, "mask_to_sensor_mm": 1.0},
        "noise": {"black_level_dn": 64.0, "read_noise_dn": 2.0, "electrons_per_dn": 4.0,
                  "saturation_dn": 4095.0},
    })


@pytest.fixture
def tiny_profile() -> Profile:
    return make_profile()


def test_shapes_and_signs(tiny_profile) -> None:
    phi = np.asarray(tiny_profile.mask.phi)
    po, qo, pc, qc = direct_system_matrices(phi, tiny_profile)
    assert po.shape == pc.shape == (24, 10)
    assert qo.shape == qc.shape == (30, 12)
    assert np.all(po >= 0) and np.all(qo >= 0)
    assert np.all(np.abs(pc) <= po + 1e-15) and np.all(np.abs(qc) <= qo + 1e-15)
    assert (pc < 0).any() and (pc > 0).any()


def test_stripe_parameters_follow_the_paper() -> None:
    prof = read_profile_file(Path(__file__).parents[2] / "thintact_sdk/data/profiles/thintact-paper.yaml")
    sp = AxisGeometry.rows_of(prof).stripe_parameters()
    assert sp.k_c == pytest.approx(31.5 / 10.0)
    assert sp.k_stripe == pytest.approx(-1.0 * 31.5 / (4.8 * 10.0))
    assert sp.l_mask_um == pytest.approx(1024 * 10.0)
    assert sp.d_stripe_px > 0


def _single_cell_locus(profile, K: int, cell: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, r) of the entries of Pc that read one flipped cell of an otherwise +1 mask."""
    gen = DirectGenerator(AxisGeometry.rows_of(profile, K), d_stripe_px=1e6)
    ones = np.ones(K)
    flipped = ones.copy()
    flipped[cell] = -1
    diff = np.abs(gen.coding(ones) - gen.coding(flipped)) / gen._scaled_fade
    r, n = np.nonzero(diff > 1.0)  # the footprint mostly inside the flipped cell
    return n.astype(float), r.astype(float)


def test_stripes_run_with_slope_k_stripe() -> None:
    # fine sensor, coarse scene: the locus of one cell spans many rows per scene column
    prof = make_profile(rows=400, cols=8, n=40, m=4, K=200, pitch_um=2.0, scene_pitch_um=40.0,
                        feature_um=10.0)
    n, r = _single_cell_locus(prof, 200, 100)
    assert len(np.unique(n)) > 20
    slope = np.polyfit(n, r, 1)[0]
    k_stripe = AxisGeometry.rows_of(prof).stripe_parameters().k_stripe
    assert slope == pytest.approx(k_stripe, rel=0.05)


def test_fade_is_centred_on_the_k_c_line_with_half_maximum_at_d_stripe() -> None:
    prof = make_profile(rows=300, cols=8, n=30, m=4, K=200, pitch_um=10.0, scene_pitch_um=31.5,
                        feature_um=20.0)
    d_stripe = 80.0
    gen = DirectGenerator(AxisGeometry.rows_of(prof), d_stripe_px=d_stripe)
    fade = gen.fade  # rows × scene columns
    peak_rows = fade.argmax(axis=0).astype(float)
    inside = (peak_rows > 0) & (peak_rows < 299)
    slope = np.polyfit(np.arange(30)[inside], peak_rows[inside], 1)[0]
    assert slope == pytest.approx(31.5 / 10.0, rel=0.02)
    # at an offset of d_stripe/2 sensor pixels from the centre line the fade is 1/2
    y_r = (np.arange(300) - 149.5) * 10.0
    col = 15
    y_n = (col - 14.5) * 31.5
    offset = np.abs(y_r - y_n) / 10.0
    half = np.interp(d_stripe / 2, offset[offset.argsort()], fade[offset.argsort(), col])
    assert half == pytest.approx(0.5, abs=0.02)
    assert SIGMOID_SOFTNESS > 0


def test_white_open_response_is_one_at_the_centre() -> None:
    prof = make_profile(rows=25, cols=31, n=11, m=13, K=50)
    po, qo, _, _ = direct_system_matrices(np.ones(50), prof)
    assert 2 * (po.sum(axis=1)[12]) * (qo.sum(axis=1)[15]) == pytest.approx(1.0, rel=1e-9)


def test_mask_outside_the_K_cells_is_closed() -> None:
    prof = make_profile(K=4)  # a 0.24 mm mask in a 1 mm field
    po, _, pc, _ = direct_system_matrices(np.ones(4), prof)
    assert po[0].max() == 0.0 and po[-1].max() == 0.0  # edge rows see no open cell
    np.testing.assert_allclose(pc, po)  # φ ≡ 1: coding equals open


def test_phi_rows_drives_the_row_matrix(tiny_profile) -> None:
    phi = np.asarray(tiny_profile.mask.phi)
    _, _, pc, qc = direct_system_matrices(phi, tiny_profile, phi_rows=-phi)
    _, _, pc2, qc2 = direct_system_matrices(phi, tiny_profile)
    np.testing.assert_allclose(pc, -pc2)
    np.testing.assert_allclose(qc, qc2)


@pytest.mark.parametrize("bad", [np.zeros(40), np.ones((2, 20)), np.array([])])
def test_bad_phi_is_refused(tiny_profile, bad) -> None:
    with pytest.raises(ValueError):
        direct_system_matrices(bad, tiny_profile)


@pytest.mark.parametrize("device,limit", [("mini", 0.005), ("wide", 0.012)])
def test_matches_the_golden_baseline_physics(golden_dir, device: str, limit: float) -> None:
    """The T2S model from direct generation reproduces the exact baseline (CONTRACTS §4)
    irradiance of the golden devices after one gain per channel."""
    d = golden_dir / device
    prof = read_profile_file(d / "profile.json")
    scenes = np.load(d / "scenes.npy")
    irradiance = np.load(d / "irradiance.npy")
    assert len(json.loads((d / "labels.json").read_text())) == scenes.shape[0]
    po, qo, pc, qc = direct_system_matrices(np.asarray(prof.mask.phi), prof)
    x = np.moveaxis(scenes, 3, 1)  # F × C × N × M
    pred = np.moveaxis(po @ x @ qo.T + pc @ x @ qc.T, 1, 3)  # F × R × S × C
    gain = (pred * irradiance).sum(axis=(0, 1, 2)) / (pred * pred).sum(axis=(0, 1, 2))
    rel = np.sqrt(np.mean((irradiance - gain * pred) ** 2) / np.mean(irradiance**2))
    assert rel < limit


@pytest.mark.parametrize("device,limit", [("mini", 0.025), ("wide", 0.045)])
def test_close_to_the_simulators_two_term_fit(golden_dir, device: str, limit: float) -> None:
    """Operator-level relative difference from SIM's best two-term fit (after one scale)."""
    pytest.importorskip("thintact_sdk.simulation.simulator")
    from thintact_masks.compare import direct_vs_simulator

    prof = read_profile_file(golden_dir / device / "profile.json")
    assert direct_vs_simulator(prof) < limit
