"""The simulator against the independent golden baseline (CONTRACTS §4)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.simulator.sim_helpers import rel_rms
from thintact_sdk.imaging.simulator import Simulator
from thintact_sdk.profile import read_profile_file

# The golden renderer's mask sits 1/8 um lower in x and in y than CONTRACTS §1 puts it (its
# pattern is T(m + 0.125 um), as a 0.25 um raster sampled at its cell centres would give). The
# offset is invisible in extended scenes (< 1e-3 either way) but a single scene row or column
# throws a 6.6 um penumbra, so there it costs 3.5e-3. Measured by a free fit on both devices:
# mini (-0.1249, -0.1250) um, wide (-0.1211, -0.1208) um; with it every frame is <= 1.71e-4.
GOLDEN_MASK_OFFSET_UM = -0.125


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


def test_wide_matches_golden_every_frame(golden_dir):
    labels = _labels(golden_dir, "wide")
    errs = _errors(golden_dir, "wide")
    for lab, e in zip(labels, errs.max(axis=1), strict=True):
        assert e < 1e-3, f"{lab}: {e:.2e}"


def test_mini_matches_golden_on_extended_scenes(golden_dir):
    """Every extended-scene frame of golden-mini to < 0.1 % with the contract's mask exactly
    where §1 puts it. The single-slit frames need the golden renderer's offset (below)."""
    labels = _labels(golden_dir, "mini")
    errs = _errors(golden_dir, "mini")
    for lab, e in zip(labels, errs.max(axis=1), strict=True):
        if lab.startswith("slit"):
            assert 2e-3 < e < 6e-3, f"{lab}: {e:.2e} (the offset's signature changed)"
        else:
            assert e < 1e-3, f"{lab}: {e:.2e}"


@pytest.mark.parametrize("name", ["mini", "wide"])
def test_golden_renderer_mask_offset_is_recovered_per_axis(golden_dir, name):
    """The offset is found, independently along x (vertical slits) and along y (horizontal
    slits), from a parabola through the slit frames' squared error at three trial offsets."""
    labels = _labels(golden_dir, name)
    for axis, prefix in ((0, "slit_v"), (1, "slit_h")):
        frames = [i for i, lab in enumerate(labels) if lab.startswith(prefix)]
        trials = np.array([-0.25, -0.0625, 0.125])
        sq = []
        for t in trials:
            off = [0.0, 0.0]
            off[axis] = float(t)
            sq.append(float(np.sum(_errors(golden_dir, name, tuple(off), frames) ** 2)))
        a, b, _ = np.polyfit(trials, sq, 2)
        assert a > 0
        assert -b / (2 * a) == pytest.approx(GOLDEN_MASK_OFFSET_UM, abs=0.012), (axis, sq)


@pytest.mark.parametrize("name", ["mini", "wide"])
def test_every_golden_frame_matches_with_the_renderer_offset(golden_dir, name):
    """With the golden renderer's 1/8 um mask offset every frame of both devices, slits
    included, is far inside the 0.1 % criterion."""
    labels = _labels(golden_dir, name)
    errs = _errors(golden_dir, name, (GOLDEN_MASK_OFFSET_UM, GOLDEN_MASK_OFFSET_UM))
    for lab, e in zip(labels, errs.max(axis=1), strict=True):
        assert e < 3e-4, f"{lab}: {e:.2e}"


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
