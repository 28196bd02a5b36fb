"""Display plugins: the pygame window checked pixel-exactly under Xvfb, the layout rules,
and the virtual display's scene slot (the calibration wizard through the pygame window is
tests/calibration/test_cal_wizard_pygame.py)."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from collections.abc import Iterator

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


@pytest.fixture(scope="module")
def xvfb() -> Iterator[str]:
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.skip("Xvfb binary not installed (Debian package xvfb); cannot test the pygame display")
    r, w = os.pipe()
    proc = subprocess.Popen(
        [exe, "-displayfd", str(w), "-screen", "0", f"{PANEL[0]}x{PANEL[1]}x24", "-nolisten", "tcp"],
        pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    os.close(w)
    try:
        with os.fdopen(r) as f:
            number = f.readline().strip()
        if not number:
            pytest.fail("Xvfb started but did not report its display number")
        yield f":{number}"
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def _read_root(display_name: str) -> np.ndarray:
    from Xlib import X
    from Xlib import display as xdisplay

    d = xdisplay.Display(display_name)
    try:
        root = d.screen().root
        geom = root.get_geometry()
        raw = root.get_image(0, 0, geom.width, geom.height, X.ZPixmap, 0xFFFFFFFF).data
        img = np.frombuffer(raw, np.uint8).reshape(geom.height, geom.width, 4)
        return img[..., [2, 1, 0]].copy()  # BGRX → RGB
    finally:
        d.close()


@pytest.mark.display
@pytest.mark.parametrize(("origin", "pitch"), [((37, 21), 31.5), ((5, 150), 63.0)])
def test_pygame_display_is_pixel_exact(xvfb: str, monkeypatch: pytest.MonkeyPatch,
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
        got = _read_root(xvfb)
        while not np.array_equal(got, want) and time.monotonic() < deadline:
            time.sleep(0.05)
            got = _read_root(xvfb)
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
