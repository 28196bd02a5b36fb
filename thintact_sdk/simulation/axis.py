"""One-axis box integrals of a piecewise-constant mask profile (the simulator's exact core).

Along one axis (x for columns, y for rows) a ray from scene coordinate ``s`` to sensor
coordinate ``u`` crosses the mask at ``m = alpha·u + beta·s`` (``alpha = z/H``,
``beta = d/H``). For a mask profile ``A(m)`` that is constant on cells (values ``A_j`` on
``[e_j, e_{j+1})``, zero outside), the double box integral over a sensor interval and a
scene interval has a closed form::

    ∫∫ A(alpha·u + beta·s) du ds = [D(m11) - D(m01) - D(m10) + D(m00)] / (alpha·beta)

with ``D`` the second antiderivative of ``A`` (piecewise quadratic) and ``mab`` the four
corners ``alpha·u_a + beta·s_b``. This is the trapezoid distribution of ``m`` integrated
exactly, however the cell edges fall inside the interval pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AxisGrid:
    """Pixel grids along one axis, all lengths in mm.

    Attributes
    ----------
    n_sensor, sensor_pitch_mm
        Number of sensor pixels and their pitch; centres at ``(i - (n-1)/2)·pitch``.
    n_scene, scene_pitch_mm
        Number of scene pixels and their pitch, centred on the same axis.
    sensor_offset_mm
        Where the centre of these sensor pixels lies on the axis (mm; 0 for a whole sensor,
        the window's centre for a window of a larger sensor:
        :func:`~thintact_sdk.simulation.tiled.window_params`).
    """

    n_sensor: int
    sensor_pitch_mm: float
    n_scene: int
    scene_pitch_mm: float
    sensor_offset_mm: float = 0.0

    def sensor_span_mm(self) -> tuple[float, float]:
        """``(first, last)`` edge of the sensor pixels (mm)."""
        half = self.n_sensor * self.sensor_pitch_mm / 2
        return self.sensor_offset_mm - half, self.sensor_offset_mm + half

    def crossing_span_mm(self, alpha: float, beta: float) -> tuple[float, float]:
        """``(lowest, highest)`` crossing point ``alpha·u + beta·s`` of any sensor and scene
        point (mm)."""
        lo, hi = self.sensor_span_mm()
        half_s = self.n_scene * self.scene_pitch_mm / 2
        return alpha * lo - beta * half_s, alpha * hi + beta * half_s

    def sensor_edges_mm(self, n_sub: int = 1) -> np.ndarray:
        """``n_sensor·n_sub + 1`` edges of the sensor pixels split into ``n_sub`` parts."""
        lo, hi = self.sensor_span_mm()
        return np.linspace(lo, hi, self.n_sensor * n_sub + 1)

    def scene_edges_mm(self, n_sub: int = 1) -> np.ndarray:
        """``n_scene·n_sub + 1`` edges of the scene pixels split into ``n_sub`` parts."""
        half = self.n_scene * self.scene_pitch_mm / 2
        return np.linspace(-half, half, self.n_scene * n_sub + 1)

    def sensor_centres_mm(self) -> np.ndarray:
        """``(n_sensor,)`` pixel centres in mm."""
        return self.sensor_offset_mm + (np.arange(self.n_sensor) - (self.n_sensor - 1) / 2) * self.sensor_pitch_mm

    def scene_centres_mm(self) -> np.ndarray:
        """``(n_scene,)`` pixel centres in mm."""
        return (np.arange(self.n_scene) - (self.n_scene - 1) / 2) * self.scene_pitch_mm

    def max_offset_mm(self) -> float:
        """Largest ``|s - u|`` between any scene point and any sensor point (mm)."""
        return (self.n_sensor * self.sensor_pitch_mm + self.n_scene * self.scene_pitch_mm) / 2 \
            + abs(self.sensor_offset_mm)


def mask_cell_edges_mm(k_cells: int, feature_mm: float) -> np.ndarray:
    """``(K+1,)`` edges of K mask cells of side ``feature_mm`` centred on the axis (CONTRACTS §1)."""
    return (np.arange(k_cells + 1) - k_cells / 2) * feature_mm


def second_antiderivative(edges_mm: np.ndarray, values: np.ndarray, t_mm: np.ndarray) -> np.ndarray:
    """``D(t) = ∫_{-inf}^t ∫_{-inf}^tau A(m) dm dtau`` of a piecewise-constant profile.

    Parameters
    ----------
    edges_mm
        ``(J+1,)`` increasing cell edges in mm.
    values
        ``(V, J)`` profile values on the cells (several profiles sharing the edges);
        zero outside ``[edges[0], edges[-1])``.
    t_mm
        Points (any shape) in mm.

    Returns
    -------
    numpy.ndarray
        ``(V,) + t_mm.shape`` values of D in mm² (times the profile's unit).
    """
    widths = np.diff(edges_mm)
    n_v, n_j = values.shape
    # per interval k (0: below the first edge, J + 1: beyond the last) the quadratic
    # D(t) = D_k + C_k·dt + A_k·dt²/2 with dt = t - (its left edge); table[v] = (D, C, A/2)
    table = np.zeros((n_v, 3, n_j + 2))
    table[:, 1, 2:] = np.cumsum(values * widths, axis=1)  # C at edges 1..J
    table[:, 0, 2:] = np.cumsum(table[:, 1, 1:-1] * widths + values * widths**2 / 2, axis=1)
    table[:, 2, 1:-1] = values / 2
    left = np.concatenate([edges_mm[:1], edges_mm])  # interval k's left edge
    t = np.asarray(t_mm, dtype=float)
    flat = t.ravel()
    w0 = float(widths[0])
    if np.all(np.abs(widths - w0) <= 1e-9 * abs(w0)):
        # uniform cells (every mask profile): the interval by division, not a search; at an
        # edge either neighbour gives the same D (it is continuously differentiable there)
        k = np.floor((flat - edges_mm[0]) / w0).astype(np.intp) + 1
        np.clip(k, 0, n_j + 1, out=k)
    else:
        k = np.searchsorted(edges_mm, flat, side="right")
    dt = flat - left[k]
    out = np.empty((n_v, flat.size))
    for v in range(n_v):  # Horner in place, gathering from each profile's small tables
        o = out[v]
        np.multiply(table[v, 2][k], dt, out=o)
        o += table[v, 1][k]
        o *= dt
        o += table[v, 0][k]
    return out.reshape((n_v,) + t.shape)


def box_box_integrals(
    grid: AxisGrid,
    alpha: float,
    beta: float,
    edges_mm: np.ndarray,
    values: np.ndarray,
    n_sub_sensor: int,
    n_sub_scene: int,
    profile_shifts_mm: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact mask integrals over every (sensor sub-interval, scene sub-interval) pair.

    Parameters
    ----------
    grid
        The axis' pixel grids.
    alpha, beta
        ``m = alpha·u + beta·s`` (``z/H`` and ``d/H`` for straight rays).
    edges_mm, values
        The piecewise-constant mask profile(s): ``(J+1,)`` edges, ``(V, J)`` values.
    n_sub_sensor, n_sub_scene
        Sub-intervals per sensor and per scene pixel (the smooth radiometric factor is
        later evaluated at each sub-rectangle centre).
    profile_shifts_mm
        Optional ``(T,)`` displacements: the integrals of ``A(m - t)`` for each, stacked
        in a leading axis of ``integrals``.

    Returns
    -------
    integrals
        ``(V, n_sensor, n_scene, n_sub_sensor, n_sub_scene)``:
        ``∫∫ A(alpha·u + beta·s) du ds`` over each sub-rectangle, in mm² (with
        ``profile_shifts_mm``: ``(T, V, ...)``).
    offsets_mm
        ``(n_sensor, n_scene, n_sub_sensor, n_sub_scene)``: ``s - u`` at each
        sub-rectangle centre in mm.
    """
    ue = grid.sensor_edges_mm(n_sub_sensor)
    se = grid.scene_edges_mm(n_sub_scene)
    corners = alpha * ue[:, None] + beta * se[None, :]
    shifts = np.zeros(1) if profile_shifts_mm is None else np.asarray(profile_shifts_mm, float)
    d = second_antiderivative(edges_mm, values, corners[None] - shifts[:, None, None])
    d = np.moveaxis(d, 1, 0)  # (T, V, corners...)
    box = (d[..., 1:, 1:] - d[..., :-1, 1:] - d[..., 1:, :-1] + d[..., :-1, :-1]) / (alpha * beta)
    n_t, n_v = shifts.size, values.shape[0]
    r, n = grid.n_sensor, grid.n_scene
    box = box.reshape(n_t, n_v, r, n_sub_sensor, n, n_sub_scene).transpose(0, 1, 2, 4, 3, 5)
    if profile_shifts_mm is None:
        box = box[0]
    uc = (ue[1:] + ue[:-1]) / 2
    sc = (se[1:] + se[:-1]) / 2
    off = sc[None, :] - uc[:, None]
    off = off.reshape(r, n_sub_sensor, n, n_sub_scene).transpose(0, 2, 1, 3)
    return box, off
