"""The simulator's exact core: the second antiderivative of a piecewise-constant profile,
against numerical double integration, on uniform cells (the division path) and on
irregular edges (the search path), at and beyond the edges."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from thintact_sdk.simulation.axis import mask_cell_edges_mm, second_antiderivative


def _numerical(edges: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``D`` by cumulative sums on a fine grid that contains every edge: on each grid step
    the profile is one cell's constant, so ``C`` is exact at the grid points and the
    trapezoid rule integrates the piecewise-linear ``C`` exactly; ``D`` between grid points
    is interpolated linearly (error ≤ step²·|A|/8 ≈ 1e-12)."""
    grid = np.union1d(np.linspace(edges[0] - 1.1, edges[-1] + 1.1, 800_001), edges)
    mid = (grid[1:] + grid[:-1]) / 2
    cell = np.searchsorted(edges, mid, side="right") - 1
    inside = (cell >= 0) & (cell < len(edges) - 1)
    prof = np.zeros((values.shape[0], mid.size))
    prof[:, inside] = values[:, cell[inside]]
    c = np.concatenate([np.zeros((values.shape[0], 1)), np.cumsum(prof * np.diff(grid), axis=1)], axis=1)
    d = cumulative_trapezoid(c, grid, axis=1, initial=0.0)
    return np.stack([np.interp(t, grid, row) for row in d])


@pytest.mark.parametrize("uniform", [True, False])
def test_second_antiderivative_is_the_double_integral(uniform):
    rng = np.random.default_rng(7)
    if uniform:
        edges = mask_cell_edges_mm(31, 0.02)
    else:
        edges = np.sort(rng.uniform(-0.3, 0.3, 32))
    values = rng.standard_normal((3, edges.size - 1))
    t = np.concatenate([rng.uniform(edges[0] - 0.04, edges[-1] + 0.04, 198), edges,
                        [edges[0] - 1.0, edges[-1] + 1.0]])
    got = second_antiderivative(edges, values, t.reshape(2, -1))
    assert got.shape == (3, 2, t.size // 2)
    want = _numerical(edges, values, t)
    scale = np.abs(want).max()
    assert np.abs(got.reshape(3, -1) - want).max() <= 1e-9 * scale
    assert np.all(got.reshape(3, -1)[:, t < edges[0]] == 0.0)
