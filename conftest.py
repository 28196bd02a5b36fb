"""What every test of the repository shares, the core's (``tests/``) and each plugin's
(``plugins/<plugin>/tests/``, also when run alone from the repository root): a private cache,
and an X server for the display tests."""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Callable, Iterator

import numpy as np
import pytest


@pytest.fixture(scope="session", autouse=True)
def _private_user_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Per-host caches (e.g. the decoders' measured backends) go to a session directory (one
    per test process), never to the user's ~/.cache."""
    os.environ["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("xdg-cache"))
    os.environ.pop("THINTACT_CACHE_DIR", None)
    os.environ.pop("THINTACT_BACKEND", None)


XVFB_SCREEN_PX = (320, 200)
"""Width × height of the X screen the ``xvfb`` fixture starts (the display tests' panel)."""


@pytest.fixture(scope="module")
def xvfb() -> Iterator[str]:
    """An Xvfb server of :data:`XVFB_SCREEN_PX`, 24-bit, no TCP: yields its display name
    (``":N"``); skips where the ``Xvfb`` binary (Debian package xvfb) is missing."""
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.skip("Xvfb binary not installed (Debian package xvfb); cannot test the pygame display")
    r, w = os.pipe()
    width, height = XVFB_SCREEN_PX
    proc = subprocess.Popen(
        [exe, "-displayfd", str(w), "-screen", "0", f"{width}x{height}x24", "-nolisten", "tcp"],
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


@pytest.fixture
def x_screen() -> Callable[[str], np.ndarray]:
    """``read(display_name)`` → what the X server's root window shows, ``H × W × 3`` uint8 RGB."""

    def read(display_name: str) -> np.ndarray:
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

    return read
