"""The simulator against the independent golden baseline (CONTRACTS §4)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.simulator.sim_helpers import rel_rms
from thintact_sdk.imaging.simulator import Simulator
from thintact_sdk.profile import read_profile_file


def _fit(golden_dir, name):
    d = golden_dir / name
    prof = read_profile_file(d / "profile.json")
    scenes = np.load(d / "scenes.npy")
    gold = np.load(d / "irradiance.npy")
    labels = json.loads((d / "labels.json").read_text())
    y = Simulator(prof).forward_batch(scenes)
    gain = np.array([y[..., c].ravel() @ gold[..., c].ravel() / (y[..., c].ravel() @ y[..., c].ravel())
                     for c in range(3)])
    return labels, [rel_rms(y[f] * gain, gold[f]) for f in range(len(labels))]


def test_wide_matches_golden_every_frame(golden_dir):
    labels, errs = _fit(golden_dir, "wide")
    for lab, e in zip(labels, errs, strict=True):
        assert e < 1e-3, f"{lab}: {e:.2e}"


def test_mini_matches_golden(golden_dir):
    """Every extended-scene frame of golden-mini to < 0.1 %. The four single-slit frames
    differ by 0.35-0.4 %: the difference sits on shadow-edge pixels, where a converged
    brute force agrees with this simulator (see the next test), not with the golden file."""
    labels, errs = _fit(golden_dir, "mini")
    for lab, e in zip(labels, errs, strict=True):
        limit = 5e-3 if lab.startswith("slit") else 1e-3
        assert e < limit, f"{lab}: {e:.2e}"


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
