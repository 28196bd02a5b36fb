"""Ghost search on independent-style recordings: the 2-D offset exact and the strength within
±20 % of the truth for 3-10 % ghosts, diagonal (not separable) and along an axis (separable),
monochrome and RGB; a healthy unit's scans stay well below the reporting threshold."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from independent_device import Ghost, small_profile, write_recording

from thintact_sdk.calibration.collect import collect_slits
from thintact_sdk.calibration.ghost import MIN_STRENGTH, _out_factors, _signature
from thintact_sdk.calibration.health import HealthReport, assess
from thintact_sdk.calibration.pipeline import CalibrationOptions, solve_matrices


def _health(root: Path, channels: tuple[str, ...], ghost: Ghost | None, seed: int) -> HealthReport:
    profile = small_profile(channels)
    rec = write_recording(root / "rec", profile, seed=seed, defects=[ghost] if ghost else [])
    collection = collect_slits(rec)
    sm, _ = solve_matrices(collection, CalibrationOptions(), profile)
    return assess(rec, collection, sm, 1)


CASES = [
    (("mono",), Ghost(6, -9, 0.03), 4),  # faintest diagonal: the compressed slits read it at half
    (("mono",), Ghost(-7, 12, 0.10), 5),  # strongest: its edge band is not left out of the fit
    (("R", "G", "B"), Ghost(6, -9, 0.05), 1),  # the case (was reported at (+6, 0), 3.5 %)
    (("mono",), Ghost(0, 11, 0.03), 4),  # separable, along the columns
    (("mono",), Ghost(-10, 0, 0.05), 5),  # separable, along the rows
]


@pytest.mark.parametrize(("channels", "ghost", "seed"), CASES,
                         ids=[f"{len(c)}ch-{g.rows:+d}{g.cols:+d}-{g.strength:.2f}" for c, g, _ in CASES])
def test_ghost_offset_exact_and_strength_within_20_percent(tmp_path: Path, channels: tuple[str, ...],
                                                           ghost: Ghost, seed: int) -> None:
    health = _health(tmp_path, channels, ghost, seed)
    found = [d for d in health.defects if d.kind == "ghost"]
    assert len(found) == 1, [d.describe() for d in health.defects]
    assert found[0].offset_px == (ghost.rows, ghost.cols)
    assert found[0].strength == pytest.approx(ghost.strength, rel=0.2)
    assert ("not separable" in found[0].note) == (ghost.rows != 0 and ghost.cols != 0)


def test_healthy_unit_ghost_scans_stay_below_the_threshold(tmp_path: Path) -> None:
    health = _health(tmp_path, ("mono",), None, seed=3)
    assert not [d for d in health.defects if d.kind == "ghost"]
    strongest = max(s.estimate if s.estimate == s.estimate else s.value for s in health.ghost_scans)
    assert strongest < 0.8 * MIN_STRENGTH


def test_all_lags_at_once_match_one_shift_per_lag() -> None:
    # the slit map's out-lag factors by cross-correlation against shifting once per lag
    rng = np.random.default_rng(1)
    left = rng.standard_normal((7, 40, 5))
    lead = rng.standard_normal((7, 40, 2)) + np.linspace(0.0, 3.0, 40)[None, :, None]  # an open-like trend
    keep = np.ones(40)
    keep[[3, 17, 18]] = 0.0  # lines of located defects
    lags = [-13, -5, -2, 2, 6, 13]
    x, gram = _out_factors(left, lead, lags, keep)
    for j, lag in enumerate(lags):
        sig = _signature(lead, lag, keep)
        np.testing.assert_allclose(x[j], left.transpose(0, 2, 1) @ sig, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(gram[j], np.einsum("naq,nar->qr", sig, sig), rtol=1e-9, atol=1e-9)
