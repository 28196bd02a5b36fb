"""Display plugins: the pygame window checked pixel-exactly under Xvfb, the layout rules,
and the virtual display's scene slot (the calibration wizard through the pygame window is
tests/calibration/test_cal_wizard_pygame.py)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pytest
from thintact_displays.layout import panel_layout, scene_to_rgb8

from thintact_sdk.device.registry import get_registry
from thintact_sdk.errors import DeviceError, ProfileError
from thintact_sdk.formats.profiles import Profile, load_profile

PANEL = (320, 200)


def _profile(origin: tuple[int, int], scene_pitch_um: float = 31.5, index: int = 0) -> Profile:
    base = load_profile("virtual-mini").contract_dict()
    base["scene"] = {"rows": 20, "cols": 30, "pixel_pitch_um": scene_pitch_um}
    base["display"] = {"plugin": "pygame", "pixel_pitch_um": 31.5, "origin_px": list(origin),
                       "display_index": index, "settle_s": 0.0}
    return Profile.model_validate(base)




@pytest.mark.display
@pytest.mark.parametrize(("origin", "pitch"), [((37, 21), 31.5), ((5, 150), 63.0)])
def test_pygame_display_is_pixel_exact(xvfb: str, x_screen: Callable[[str], np.ndarray], monkeypatch: pytest.MonkeyPatch,
                                       origin: tuple[int, int], pitch: float) -> None:
    monkeypatch.setenv("DISPLAY", xvfb)
    monkeypatch.setenv("SDL_VIDEODRIVER", "x11")
    prof = _profile(origin, pitch)
    disp = get_registry().create("display", "pygame", prof, {})
    scene = np.random.default_rng(1).random((20, 30, 3), dtype=np.float32)
    scene[0, 0] = [1.0, 0.0, 0.5]
    disp.open()
    try:
        assert disp.panel_size_px == PANEL
        disp.show(scene)
        want = np.zeros((PANEL[1], PANEL[0], 3), np.uint8)
        block = scene_to_rgb8(scene, panel_layout(prof).block_px)
        want[origin[1]:origin[1] + block.shape[0], origin[0]:origin[0] + block.shape[1]] = block
        deadline = time.monotonic() + 5.0
        got = x_screen(xvfb)
        while not np.array_equal(got, want) and time.monotonic() < deadline:
            time.sleep(0.05)
            got = x_screen(xvfb)
        np.testing.assert_array_equal(got, want)
        assert tuple(got[origin[1], origin[0]]) == (255, 0, 128)
    finally:
        disp.close()


@pytest.mark.display
def test_pygame_display_refuses_area_off_panel_and_missing_display(
    xvfb: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("DISPLAY", xvfb)
    monkeypatch.setenv("SDL_VIDEODRIVER", "x11")
    with pytest.raises(DeviceError, match="does not fit"):
        get_registry().create("display", "pygame", _profile((300, 10)), {}).open()
    with pytest.raises(DeviceError, match="display 3 not found"):
        get_registry().create("display", "pygame", _profile((0, 0), index=3), {}).open()


def test_layout_needs_integer_pitch_ratio() -> None:
    assert panel_layout(_profile((1, 2), 94.5)).block_px == 3
    with pytest.raises(ProfileError, match="integer multiple"):
        panel_layout(_profile((1, 2), 40.0))


def test_scene_to_rgb8_rounds_and_clips() -> None:
    out = scene_to_rgb8(np.array([[[-0.1, 0.5, 1.2]]]))
    assert out.tolist() == [[[0, 128, 255]]]


def test_virtual_display_feeds_the_scene_slot() -> None:
    bench = pytest.importorskip("thintact_virtual.bench", reason="virtual sensor plugin not installed yet")
    prof = load_profile("virtual-mini")
    disp = get_registry().create("display", "virtual", prof, {"slot": "cal-test-slot"})
    scene = np.full((prof.scene.rows, prof.scene.cols, 3), 0.25, np.float32)
    with disp:
        disp.show(scene)
        np.testing.assert_array_equal(bench.get_scene_slot("cal-test-slot").get(), scene)
        with pytest.raises(ValueError, match="scene must be"):
            disp.show(scene[:-1])
    assert bench.get_scene_slot("cal-test-slot").get() is None
