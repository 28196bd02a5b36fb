"""Issue 34 item 4: soft shading blemishes (dust on the cover glass: a Gaussian shadow 5-12 %
deep, σ 2-8 px) are found from the flat and validation frames, located within 2 px with
their depth, and a healthy unit still shows none."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from independent_device import Dust, small_profile, write_recording

from thintact_sdk.calibration.blemish import RatioMap, detection_z, find_blemishes
from thintact_sdk.calibration.collect import collect_slits
from thintact_sdk.calibration.health import assess
from thintact_sdk.calibration.pipeline import CalibrationOptions, solve_matrices
from thintact_sdk.calibration.verdict import judge
from thintact_sdk.formats.profiles import CalibrationLimits


def _health(root: Path, seed: int, defects: list[Dust], channels: tuple[str, ...] = ("R", "G", "B")):  # noqa: ANN202
    prof = small_profile(channels)
    rec = write_recording(root / "rec", prof, seed=seed, defects=list(defects))
    col = collect_slits(rec)
    sm, _ = solve_matrices(col, CalibrationOptions(), prof)
    return assess(rec, col, sm, 1)


@pytest.mark.parametrize("sigma_px", [2.0, 4.0, 8.0])
@pytest.mark.parametrize("depth", [0.05, 0.12])
def test_a_soft_shadow_is_found_located_and_measured(tmp_path: Path, sigma_px: float, depth: float) -> None:
    h = _health(tmp_path, 3, [Dust(row=30, col=25, sigma_px=sigma_px, depth=depth)])
    shadows = [d for d in h.defects if d.kind in ("shading blemish", "dust speck")]
    assert len(shadows) == 1, [d.describe() for d in h.defects]
    d = shadows[0]
    assert abs(d.centre[0] - 30) <= 2 and abs(d.centre[1] - 25) <= 2
    blemish = d if d.kind == "shading blemish" else None
    text = d.describe() if blemish is not None else d.note
    assert "%" in text and "σ" in text
    if blemish is not None:
        assert blemish.strength == pytest.approx(depth, rel=0.25)
    # the unit fails, naming it with a fix
    v = judge([], None, h, CalibrationLimits())
    assert d.kind in [f.what for f in v.failures]


@pytest.mark.parametrize("seed,channels", [(1, ("R", "G", "B")), (5, ("R", "G", "B")), (4, ("mono",))])
def test_a_healthy_unit_shows_no_blemish(tmp_path: Path, seed: int, channels: tuple[str, ...]) -> None:
    h = _health(tmp_path, seed, [], channels)
    assert h.defects == [], [d.describe() for d in h.defects]


def test_the_threshold_follows_the_map_and_the_noise() -> None:
    """Pure noise of any level gives no blemish; a shadow well above it is found with its
    depth; a bigger sensor has more places for a false alarm, so a higher threshold."""
    assert detection_z((1024, 1280)) > detection_z((64, 80)) > 3.0
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:64, 0:80]
    for noise in (0.002, 0.02):
        sig = np.full((64, 80), noise)
        flat = RatioMap(1.0 + rng.normal(0, noise, (64, 80)), sig, 4)
        assert find_blemishes(flat) == []
        shadow = 1.0 - 6 * noise * np.exp(-((yy - 40) ** 2 + (xx - 20) ** 2) / (2 * 4.0**2))
        found = find_blemishes(RatioMap(flat.ratio * shadow, sig, 4))
        assert len(found) == 1
        b = found[0]
        assert abs(b.row - 40) <= 1 and abs(b.col - 20) <= 1 and b.depth == pytest.approx(6 * noise, rel=0.2)
