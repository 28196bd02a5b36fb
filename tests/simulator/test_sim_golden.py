"""The simulator against the independent golden baseline (CONTRACTS §4)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.simulator.sim_helpers import rel_rms
from thintact_sdk.formats.profiles import read_profile_file
from thintact_sdk.simulation.simulator import Simulator

# The golden baseline was regenerated (2026-11-23) with the reference renderer's 1/8 um mask
# offset fixed, so the contract-exact simulator (the mask exactly where CONTRACTS §1 puts it)
# now matches every frame of both devices, single-row and single-column slits included.
CONTRACT_TOLERANCE = 1e-3  # CONTRACTS §4: relative RMS per frame
MEASURED_TOLERANCE = 3e-4  # what holds now: worst frame about 2.2e-4


def _profile(golden_dir, name, offset_um=(0.0, 0.0)):
    prof = read_profile_file(golden_dir / name / "profile.json")
    if offset_um == (0.0, 0.0):
        return prof
    return prof.model_copy(update={"physics": {"mask_misalignment": {
        "angle_deg": 0.0, "dx_um": offset_um[0], "dy_um": offset_um[1]}}})


def _errors(golden_dir, name, offset_um=(0.0, 0.0), frames=None):
    """Relative RMS per frame and channel after one gain per channel (shared by the frames)."""
    d = golden_dir / name
    scenes = np.load(d / "scenes.npy")
    frames = list(range(len(scenes))) if frames is None else frames
    gold = np.load(d / "irradiance.npy")[frames]
    y = Simulator(_profile(golden_dir, name, offset_um)).forward_batch(scenes[frames])
    gain = np.einsum("frsc,frsc->c", gold, y) / np.einsum("frsc,frsc->c", y, y)
    return np.array([[rel_rms(y[i, ..., c] * gain[c], gold[i, ..., c]) for c in range(3)]
                     for i in range(len(frames))])


def _labels(golden_dir, name):
    return json.loads((golden_dir / name / "labels.json").read_text())


@pytest.mark.parametrize("name", ["mini", "wide"])
def test_every_golden_frame_matches_contract_exact(golden_dir, name):
    """Every frame of both devices, slits included, with the mask exactly where CONTRACTS §1
    puts it: within the contract's 0.1 % and within the tighter figure that now holds."""
    labels = _labels(golden_dir, name)
    errs = _errors(golden_dir, name)
    assert len(labels) == len(errs)
    for lab, e in zip(labels, errs.max(axis=1), strict=True):
        assert e < CONTRACT_TOLERANCE, f"{lab}: {e:.2e}"
        assert e < MEASURED_TOLERANCE, f"{lab}: {e:.2e}"


@pytest.mark.parametrize("name", ["mini", "wide"])
def test_golden_mask_offset_fits_to_zero_per_axis(golden_dir, name):
    """A free fit of the mask offset, independently along x (vertical slits) and along y
    (horizontal slits), from a parabola through the slit frames' squared error at three trial
    offsets, lands at zero: the simulator's mask sits where the reference renderer's does."""
    labels = _labels(golden_dir, name)
    for axis, prefix in ((0, "slit_v"), (1, "slit_h")):
        frames = [i for i, lab in enumerate(labels) if lab.startswith(prefix)]
        assert frames, prefix
        trials = np.array([-0.125, 0.0, 0.125])
        sq = []
        for t in trials:
            off = [0.0, 0.0]
            off[axis] = float(t)
            sq.append(float(np.sum(_errors(golden_dir, name, tuple(off), frames) ** 2)))
        a, b, _ = np.polyfit(trials, sq, 2)
        assert a > 0
        assert -b / (2 * a) == pytest.approx(0.0, abs=0.012), (axis, sq)


def test_mini_slit_edge_pixel_against_converged_quadrature(golden_dir):
    """Pixel (17, 139) of golden-mini's slit_h_7 frame (a shadow edge) by a quadrature that
    is fine along y (where the edge is) and coarser along x."""
    d = golden_dir / "mini"
    prof = read_profile_file(d / "profile.json")
    scenes = np.load(d / "scenes.npy")
    y = Simulator(prof).forward(scenes[6])[17, 139, 0]
    p, ps, z, dd = 0.01, 0.0315, 4.8, 1.0
    h, k, delta = z + dd, 128, 0.02
    phi = np.asarray(prof.mask.phi, float)
    rows, cols, n_rows, n_cols = 128, 160, 50, 64
    lit = np.nonzero(scenes[6, :, 0, 0])[0]
    assert lit.tolist() == [7]
    ny, nx = 160, 12
    oy = (np.arange(ny) + 0.5) / ny - 0.5
    ox = (np.arange(nx) + 0.5) / nx - 0.5
    uy = (17 - (rows - 1) / 2) * p + oy * p
    sy = (7 - (n_rows - 1) / 2) * ps + oy * ps
    u_y, s_y = (a.ravel() for a in np.meshgrid(uy, sy, indexing="ij"))
    ux = (139 - (cols - 1) / 2) * p + ox * p

    def cell(m):
        j = np.floor(m / delta + k / 2).astype(int)
        return np.clip(j, 0, k - 1), (j >= 0) & (j < k)

    jy, oky = cell(u_y + (s_y - u_y) * dd / h)
    total = 0.0
    for m in range(n_cols):
        sx = (m - (n_cols - 1) / 2) * ps + ox * ps
        u_x, s_x = (a.ravel() for a in np.meshgrid(ux, sx, indexing="ij"))
        jx, okx = cell(u_x + (s_x - u_x) * dd / h)
        dx, dy = (s_x - u_x)[None, :], (s_y - u_y)[:, None]
        t = np.where(oky[:, None] & okx[None, :], (1 + phi[jy][:, None] * phi[jx][None, :]) / 2, 0)
        total += float((h**2 / (h**2 + dx**2 + dy**2) ** 2 * t).mean()) * ps * ps
    assert y == pytest.approx(total, rel=5e-4)
