"""Brute-force reference of the imaging kernel (tiny devices only; for tests and benchmarks).

Direct 4-D midpoint quadrature: ``n_sensor²`` points in every sensor pixel times ``n_scene²``
points in every scene pixel, each ray evaluated with the full non-separable physics (sharp
mask, rotated/shifted pattern, leakage, ``cos^(4+p)`` radiometry, Snell refraction). Its
own error falls as the sample counts grow; it shares no code with the fast paths except
the small physics formulas of :mod:`thintact_sdk.simulation.effects`. With refraction, Snell's law is
solved once on a table of :data:`SNELL_TABLE_POINTS` lateral offsets (uniform in ρ up to the
largest the device has) and read by linear interpolation: the table's error, ``κ''·Δρ²/8``,
is below 1e-9 relative for any device this renderer can afford.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.formats.profiles import Profile
from thintact_sdk.simulation.effects import mask_misalignment, refraction, resolve_physics

SNELL_TABLE_POINTS = 200_001
"""Lateral offsets at which the brute force solves Snell's law (uniform in ρ)."""


def _mask_value(mx: np.ndarray, my: np.ndarray, profile: Profile, physics: dict) -> np.ndarray:
    mis = physics.get("mask_misalignment", {})
    px, py = mask_misalignment.pattern_coordinates(
        mx, my, mis.get("angle_deg", 0.0), mis.get("dx_um", 0.0), mis.get("dy_um", 0.0))
    k = profile.mask.K
    delta = profile.mask.feature_um * 1e-3
    jx = np.floor(px / delta + k / 2).astype(np.int64)
    jy = np.floor(py / delta + k / 2).astype(np.int64)
    inside = (jx >= 0) & (jx < k) & (jy >= 0) & (jy < k)
    phi = np.asarray(profile.mask.phi, float)
    phi_r = np.asarray(profile.mask.rows_vector, float)
    open_ = phi_r[np.clip(jy, 0, k - 1)] * phi[np.clip(jx, 0, k - 1)] > 0
    t = physics.get("mask_leakage", {}).get("transmittance", 0.0)
    return np.where(inside, np.where(open_, 1.0, t), 0.0)


def reference_kernel(profile: Profile, n_sensor: int = 8, n_scene: int = 8,
                     sensor_pixels: np.ndarray | None = None,
                     scene_pixels: np.ndarray | None = None) -> np.ndarray:
    """The imaging operator as a dense matrix by brute force.

    Parameters
    ----------
    profile
        The device (``physics`` as in the simulator's kernel stage).
    n_sensor, n_scene
        Midpoint samples per axis in every sensor pixel and every scene pixel.
    sensor_pixels, scene_pixels
        Optional flat (row-major) indices of the sensor and scene pixels to compute
        (default all): a window of a larger device.

    Returns
    -------
    numpy.ndarray
        ``(R·S, N·M)`` (or the selected rows/columns): pixel-averaged irradiance at sensor
        pixel ``(r, c)`` (row-major) per unit radiance of scene pixel ``(n, m)`` (same units
        as the simulator).
    """
    ph = resolve_physics(profile.physics)
    g = ph.get("geometry", {})
    z = g.get("scene_to_mask_mm") or profile.geometry.scene_to_mask_mm
    d = g.get("mask_to_sensor_mm") or profile.geometry.mask_to_sensor_mm
    n_idx = ph.get("refraction", {}).get("n_scene_side", 1.0)
    p_exp = ph.get("pixel_angular_response", {}).get("exponent", 0.0)
    rows, cols, pitch = profile.sensor.rows, profile.sensor.cols, profile.sensor.pixel_pitch_um * 1e-3
    nr, nc, spitch = profile.scene.rows, profile.scene.cols, profile.scene.pixel_pitch_um * 1e-3

    def points(n: int, pitch_mm: float, k: int) -> np.ndarray:
        centres = (np.arange(n) - (n - 1) / 2) * pitch_mm
        off = ((np.arange(k) + 0.5) / k - 0.5) * pitch_mm
        return centres[:, None] + off[None, :]  # (n, k)

    uy, ux = points(rows, pitch, n_sensor), points(cols, pitch, n_sensor)
    sy, sx = points(nr, spitch, n_scene), points(nc, spitch, n_scene)
    # sensor samples: (R·S, n², 2); scene samples: (N·M, k², 2)
    u_y = np.broadcast_to(uy[:, None, :, None], (rows, cols, n_sensor, n_sensor)).reshape(rows * cols, -1)
    u_x = np.broadcast_to(ux[None, :, None, :], (rows, cols, n_sensor, n_sensor)).reshape(rows * cols, -1)
    s_y = np.broadcast_to(sy[:, None, :, None], (nr, nc, n_scene, n_scene)).reshape(nr * nc, -1)
    s_x = np.broadcast_to(sx[None, :, None, :], (nr, nc, n_scene, n_scene)).reshape(nr * nc, -1)
    if sensor_pixels is not None:
        u_y, u_x = u_y[sensor_pixels], u_x[sensor_pixels]
    scene_idx = np.arange(nr * nc) if scene_pixels is None else np.asarray(scene_pixels)
    out = np.empty((u_y.shape[0], scene_idx.size))
    if n_idx != 1.0:
        rho_max = float(np.hypot(np.ptp(np.r_[u_x.ravel(), s_x.ravel()]),
                                 np.ptp(np.r_[u_y.ravel(), s_y.ravel()])))
        rho_t = np.linspace(0.0, rho_max * 1.001 + 1e-9, SNELL_TABLE_POINTS)
        kappa_t, factor_t = refraction.crossing_fraction_and_factor(rho_t, z, d, n_idx, p_exp)
    for col, j in enumerate(scene_idx):
        dx = s_x[j][None, None, :] - u_x[:, :, None]
        dy = s_y[j][None, None, :] - u_y[:, :, None]
        rho = np.sqrt(dx**2 + dy**2)
        if n_idx == 1.0:
            h = z + d
            kappa = np.full_like(rho, d / h)
            factor = h ** (2 + p_exp) / (h**2 + rho**2) ** ((4 + p_exp) / 2)
        else:
            kappa = np.interp(rho, rho_t, kappa_t)
            factor = np.interp(rho, rho_t, factor_t)
        mx = u_x[:, :, None] + dx * kappa
        my = u_y[:, :, None] + dy * kappa
        t = _mask_value(mx, my, profile, ph)
        out[:, col] = (factor * t).mean(axis=(1, 2)) * spitch**2
    return out


def reference_forward(profile: Profile, scene: np.ndarray, n_sensor: int = 8,
                      n_scene: int = 8) -> np.ndarray:
    """``N × M × C`` scene → ``R × S × C`` kernel output by brute force (no other effects)."""
    k = reference_kernel(profile, n_sensor, n_scene)
    x = np.asarray(scene, float).reshape(-1, scene.shape[-1])
    return (k @ x).reshape(profile.sensor.rows, profile.sensor.cols, scene.shape[-1])
