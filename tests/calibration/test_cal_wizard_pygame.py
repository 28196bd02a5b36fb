"""The calibration wizard on the real display path: the pygame display plugin's window under
Xvfb, a camera that sees what X shows at ``origin_px``."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from thintact_sdk.device.registry import get_registry
from thintact_sdk.frames import RawFrame

PANEL = (320, 200)

pytest.importorskip("thintact_displays", reason="display plugin not installed")




@pytest.mark.display
def test_wizard_through_the_pygame_display(xvfb: str, x_screen: Callable[[str], np.ndarray],
                                           monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """The whole wizard on the real display path: the camera sees what X shows at origin_px."""
    from cal_testkit import FakeCamera, FakeDisplay, channel, synthetic_matrices, synthetic_profile

    from thintact_sdk.calibration.gauge import operator_error
    from thintact_sdk.calibration.pipeline import CalibrationOptions
    from thintact_sdk.calibration.wizard import WizardSettings, run_wizard

    monkeypatch.setenv("DISPLAY", xvfb)
    monkeypatch.setenv("SDL_VIDEODRIVER", "x11")
    prof = synthetic_profile(plugin="pygame", origin_px=[13, 7], display_index=0)
    sm = synthetic_matrices()

    class ScreenCamera(FakeCamera):
        """Renders the sensing area read back from the X server (8-bit panel values)."""

        def read(self, timeout_s: float = 2.0) -> RawFrame:
            panel = x_screen(xvfb)
            self.display.current = panel[7:7 + 24, 13:13 + 32].astype(np.float32) / 255.0
            return super().read(timeout_s)

    disp = get_registry().create("display", "pygame", prof, {})
    cam = ScreenCamera(prof, sm, FakeDisplay(), noise=False)
    out = run_wizard(prof, tmp_path / "cal", cam, disp, WizardSettings(frames=1, flush=0, validation=("smooth_color",)),
                     CalibrationOptions(filter_steps=0, filter_scenes=8))
    assert out.registration is not None and out.registration.passed
    exp = out.bundle.meta["exposure_us"] / 10000.0
    for c in range(3):
        t = channel(sm, c)
        ref = type(t)(t.Po * np.sqrt(exp), t.Qo * np.sqrt(exp), t.Pc * np.sqrt(exp), t.Qc * np.sqrt(exp))
        assert operator_error(channel(out.bundle.system_matrices, c), ref) < 1e-2
