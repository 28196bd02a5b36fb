"""Location and structure statistics on synthetic residuals (no simulator)."""

from __future__ import annotations

import numpy as np

from thintact_sdk.diagnosis.imaging.locate import excess_map, find_hotspots, locate
from thintact_sdk.diagnosis.imaging.structure import find_structure

F, R, S, C = 6, 64, 80, 3


def _noise(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    signal = np.full((F, R, S, C), 1000.0)
    var = 4.0 + signal / 4.0
    resid = rng.normal(0.0, np.sqrt(var))
    return resid, signal, var


def test_pure_noise_has_no_hotspots_and_no_structure() -> None:
    resid, signal, var = _noise()
    valid = np.ones_like(resid, bool)
    z = resid / np.sqrt(var)
    assert find_hotspots(excess_map(z, valid), valid.sum(axis=(0, 3)).astype(float)) == []
    st = find_structure(resid, signal, var, valid, z)
    assert not st.significant and st.hotspots == []


def test_hotspot_rectangle_holds_the_excess() -> None:
    resid, signal, var = _noise(1)
    resid[:, 10:20, 50:65] += 3.0 * np.sqrt(var[:, 10:20, 50:65])
    valid = np.ones_like(resid, bool)
    z = resid / np.sqrt(var)
    spots = find_hotspots(excess_map(z, valid), valid.sum(axis=(0, 3)).astype(float))
    h = spots[0]
    assert h.row0 <= 12 and h.row1 >= 18 and h.col0 <= 52 and h.col1 >= 63
    assert h.share > 0.8


def test_dim_column_and_dark_spot_are_found_where_they_are() -> None:
    resid, signal, var = _noise(2)
    resid[:, :, 33, :] -= 0.04 * signal[:, :, 33, :]  # a column at 96 % response
    yy, xx = np.mgrid[0:R, 0:S]
    blot = 0.3 * np.exp(-((yy - 40) ** 2 + (xx - 12) ** 2) / 8.0)
    resid -= blot[None, :, :, None] * signal
    valid = np.ones_like(resid, bool)
    z = resid / np.sqrt(var)
    st = find_structure(resid, signal, var, valid, z)
    assert st.significant
    assert any(h.col0 <= 33 < h.col1 and h.col1 - h.col0 <= 2 and h.row1 - h.row0 == R for h in st.hotspots)
    assert any(h.row0 <= 40 < h.row1 and h.col0 <= 12 < h.col1 and h.row1 - h.row0 < 15 for h in st.hotspots)
    assert st.mask[40, 12] and st.mask[5, 33]


def test_locate_summary_names_the_worst_channel_and_frame() -> None:
    resid, signal, var = _noise(3)
    resid[2, ..., 0] *= 3.0
    valid = np.ones_like(resid, bool)
    z = resid / np.sqrt(var)
    loc = locate(z, valid, signal, resid, var, 10.0, [f"f{i}" for i in range(F)], ["R", "G", "B"])
    assert int(np.argmax(loc.by_channel)) == 0
    assert int(np.argmax(loc.by_frame)) == 2
    assert "f2" in loc.summary and "R " in loc.summary
