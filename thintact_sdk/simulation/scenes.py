"""Test scenes for simulation, mask optimisation, calibration validation and demos.

Every generator returns an ``N × M × 3`` float32 image of display values in [0, 1].
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from thintact_sdk.errors import InvalidValueError

_DATA = Path(__file__).resolve().parents[1] / "data" / "gelsight"


def white(n: int, m: int) -> np.ndarray:
    """All-white scene (paper: uniformity test)."""
    return np.ones((n, m, 3), np.float32)


def checker(n: int, m: int, period_px: int = 8) -> np.ndarray:
    """Black/white checkerboard with squares of ``period_px // 2`` px."""
    half = max(1, period_px // 2)
    yy, xx = np.mgrid[0:n, 0:m]
    v = (((yy // half) + (xx // half)) % 2).astype(np.float32)
    return np.repeat(v[..., None], 3, axis=2)


def usaf(n: int, m: int) -> np.ndarray:
    """A reshaped USAF-1951-like chart: groups of three bars, horizontal and vertical,
    whose width shrinks by 2^(1/2) from group to group, white on black, filling N × M."""
    img = np.zeros((n, m), np.float32)
    cells_y, cells_x = 3, 4
    ch, cw = n // cells_y, m // cells_x
    k = 0
    for cy in range(cells_y):
        for cx in range(cells_x):
            w = max(1, int(round(min(ch, cw) / 7 / (2 ** (k / 2)))))
            y0, x0 = cy * ch + ch // 8, cx * cw + cw // 8
            length = 5 * w
            for b in range(3):  # vertical bars
                xs = x0 + 2 * b * w
                img[y0 : y0 + length, xs : xs + w] = 1.0
            xh = x0 + 6 * w + w
            for b in range(3):  # horizontal bars
                ys = y0 + 2 * b * w
                img[ys : ys + w, xh : xh + length] = 1.0
            k += 1
    return np.repeat(img[..., None], 3, axis=2)


def smooth_color(n: int, m: int) -> np.ndarray:
    """Smooth colour gradients, one per channel."""
    yy, xx = np.mgrid[0:n, 0:m].astype(np.float32)
    r = 0.5 + 0.4 * np.sin(2 * np.pi * xx / m)
    g = 0.5 + 0.4 * np.cos(2 * np.pi * yy / n)
    b = 0.5 + 0.4 * np.sin(2 * np.pi * (xx / m + yy / n))
    return np.stack([r, g, b], axis=2).astype(np.float32)


def random_pixels(n: int, m: int, seed: int = 0) -> np.ndarray:
    """Uniform random values per pixel and channel."""
    return np.random.default_rng(seed).random((n, m, 3), dtype=np.float32)


@lru_cache(maxsize=1)
def _gelsight_pack() -> dict[str, np.ndarray]:
    with np.load(_DATA / "gelsight_ball_presses.npz", allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def gelsight_count() -> int:
    """Number of vendored GelSight press images (index 0..count-1; -1 is the no-contact frame)."""
    return int(_gelsight_pack()["imgs"].shape[0])


def gelsight(n: int, m: int, index: int = 0) -> np.ndarray:
    """A real GelSight ball press (Taxim data, MIT), resized to ``N × M``; ``index=-1`` is
    the no-contact reference frame."""
    import cv2

    pack = _gelsight_pack()
    img = pack["f0"] if index < 0 else pack["imgs"][index % gelsight_count()]
    img = cv2.resize(img, (m, n), interpolation=cv2.INTER_AREA)
    return (img.astype(np.float32) / 255.0).copy()


LIBRARY = {
    "white": white,
    "checker": checker,
    "usaf": usaf,
    "smooth_color": smooth_color,
    "random": random_pixels,
    "gelsight": gelsight,
}


def make_scene(name: str, n: int, m: int, index: int = 0) -> np.ndarray:
    """Build a library scene by name (``white``, ``checker``, ``usaf``, ``smooth_color``,
    ``random``, ``gelsight``); ``index`` selects the GelSight frame or random seed."""
    if name == "gelsight":
        return gelsight(n, m, index)
    if name == "random":
        return random_pixels(n, m, index)
    if name not in LIBRARY:
        raise InvalidValueError(f"unknown scene {name!r}; one of {', '.join(LIBRARY)}")
    return LIBRARY[name](n, m)  # type: ignore[operator]
