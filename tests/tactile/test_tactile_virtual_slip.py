"""The virtual finger's press cycle shows slip: its sheared presses (partial slip, elastic
Cattaneo–Mindlin truth) read as slipping, its pure normal presses as stuck."""

from __future__ import annotations

import numpy as np
import pytest
from thintact_virtual.tactile_scenes import (
    CYCLE,
    cycle_ball_radius_mm,
    cycle_press,
    tactile_scene,
)

from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.tactile import TactileInterpreter, TactileSimulator, scene_level_lut
from thintact_sdk.tactile.interpretation.slip import SLIPPING_RATIO, is_slipping


@pytest.fixture(scope="module")
def cycle():
    profile = load_profile("virtual-finger")
    interp = TactileInterpreter(profile, scene_level_lut(profile))
    interp.set_reference(TactileSimulator.for_profile(profile).flat().scene)
    frames = [interp.interpret(tactile_scene(profile, k)) for k in range(1, CYCLE)]
    return profile, [cycle_press(profile, k) for k in range(1, CYCLE)], frames


def test_the_ball_is_wide_enough_for_two_markers_under_the_shallowest_core(cycle):
    profile, presses, _ = cycle
    pitch = profile.tactile.marker_pitch_mm
    radius = cycle_ball_radius_mm(profile)
    assert {p.ball_radius_mm for p in presses} == {radius}
    assert np.sqrt(radius * min(p.depth_mm for p in presses)) >= pitch - 1e-9
    depths = [p.depth_mm for p in presses]
    assert depths == sorted(depths) and depths[0] == pytest.approx(0.3)
    assert [p.sheared for p in presses] == [False, True] * 4


def test_sheared_presses_slip_and_pure_normal_presses_do_not(cycle):
    _, presses, frames = cycle
    assert all(f.contact for f in frames)
    known = [f.slip_ratio is not None for f in frames]
    assert all(known), [f.slip_ratio for f in frames]
    normal = [f.slip_ratio for p, f in zip(presses, frames, strict=True) if not p.sheared]
    sheared = [f.slip_ratio for p, f in zip(presses, frames, strict=True) if p.sheared]
    assert max(normal) < min(sheared)
    assert normal == [0.0] * 4
    assert all(is_slipping(s) for s in sheared) and not any(is_slipping(s) for s in normal)
    # the shear the markers show follows the load's direction (atan2(0.5, 1))
    for p, f in zip(presses, frames, strict=True):
        if p.sheared:
            assert abs(np.arctan2(f.force_n[1], f.force_n[0]) - np.arctan2(0.5, 1.0)) < 0.3


def test_is_slipping_threshold() -> None:
    assert not is_slipping(None) and not is_slipping(SLIPPING_RATIO - 1e-6)
    assert is_slipping(SLIPPING_RATIO) and is_slipping(1.0)


def test_a_field_too_small_for_the_marker_pitch_keeps_the_calibration_ball() -> None:
    from thintact_sdk.tactile.calibration.ball_press import ball_radius_for_field

    mini = load_profile("virtual-mini")
    assert cycle_ball_radius_mm(mini) == ball_radius_for_field(mini)


@pytest.mark.timeout(300)
def test_the_virtual_finger_reports_slip_through_the_lensless_path() -> None:
    import thintact_sdk as thintact

    profile = load_profile("virtual-finger")
    with thintact.open(profile, camera_settings={"fps": 0}) as finger:
        frames = [finger.read() for _ in range(CYCLE)]
    presses = [cycle_press(profile, k) for k in range(1, CYCLE)]
    normal = [f.slip_ratio for p, f in zip(presses, frames[1:], strict=True) if not p.sheared]
    sheared = [f.slip_ratio for p, f in zip(presses, frames[1:], strict=True) if p.sheared]
    assert frames[0].slip_ratio is None  # the no-contact reference
    assert sum(s is not None for s in sheared) >= 3
    assert max(s for s in normal if s is not None) < min(s for s in sheared if s is not None)
