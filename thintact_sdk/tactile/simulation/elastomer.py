"""The elastomer's smoothing of a pressed shape, with no border where the gel has none.

The tactile simulator, the calibration's ball model and the tactile diagnosis shape the
membrane as a sharp indentation smoothed by a Gaussian (paper §VI-C). The camera sees a
window of a gel that goes on beyond it, and the indenter is defined beyond the window too,
so the Gaussian must not read zeros (a flat, unpressed gel) past the frame's edge where the
shape is not zero there: a press whose contact crosses the edge would be made shallower and
steeper at the edge than the same press in the middle (a zero-depth border assumption).

Here the sharp shape is evaluated on the frame padded by the smoothing's reach, and kept on
the smallest window that holds the frame and the shape's support (its nonzero pixels, grown
by a margin the caller needs): outside that window the shape *is* zero, so a Gaussian with
zeros beyond the window is exact on the frame. A press inside the frame keeps the frame as
its window (nothing more to compute); one crossing the edge carries its part beyond it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

TRUNCATE = 4.0
"""Kernel reach in standard deviations (scipy's ``gaussian_filter`` default)."""


def reach_px(sigma_px: float) -> int:
    """Pixels a Gaussian of ``sigma_px`` reaches on each side (0 without smoothing)."""
    return int(TRUNCATE * sigma_px + 0.5) if sigma_px > 0 else 0


def smooth(values: np.ndarray, sigma_px: float) -> np.ndarray:
    """``values`` smoothed by the Gaussian of ``sigma_px`` pixels, zeros beyond the array
    (exact on a :class:`GelWindow`'s array); unchanged without smoothing."""
    if sigma_px <= 0:
        return values
    return gaussian_filter(values, sigma_px, truncate=TRUNCATE, mode="constant")


@dataclass(frozen=True)
class GelWindow:
    """Where an ``N × M`` frame lies in a window of the gel around it.

    Attributes
    ----------
    shape
        ``(N, M)`` of the frame.
    origin
        ``(row, col)`` of the frame's first pixel in the window's arrays.
    """

    shape: tuple[int, int]
    origin: tuple[int, int]

    def frame(self, values: np.ndarray) -> np.ndarray:
        """The frame's ``N × M`` part of an array on the window."""
        r, c = self.origin
        return values[r : r + self.shape[0], c : c + self.shape[1]]


def gel_window(sharp_at: Callable[[np.ndarray, np.ndarray], np.ndarray],
               shape: tuple[int, int], pad: int, grow: int = 0) -> tuple[np.ndarray, GelWindow]:
    """A sharp shape on the window of the gel a smoothing of the frame needs (module
    docstring).

    Parameters
    ----------
    sharp_at
        The sharp shape (≥ 0, zero where nothing presses) at pixel indices: called once with
        ``(rows, cols)`` float64 arrays of the frame padded by ``pad`` pixels on every side
        (the frame's pixels keep their indices; the padding's are negative or ≥ N, M).
    shape
        ``(N, M)`` of the frame.
    pad
        How far beyond the frame the shape can matter (the reach of the smoothings that
        follow, added up when they are chained).
    grow
        Margin (px) around the shape's support that the window also holds (a smoothed
        shape is nonzero there: a second smoothing, or central differences, read it).

    Returns
    -------
    (numpy.ndarray, GelWindow)
        The shape on the window (float64) and where the frame lies in it.
    """
    n, m = shape
    rr, cc = np.mgrid[-pad : n + pad, -pad : m + pad]
    sharp = np.asarray(sharp_at(rr.astype(np.float64), cc.astype(np.float64)), np.float64)
    top, left, bottom, right = pad, pad, pad + n, pad + m
    rows = np.flatnonzero(sharp.any(axis=1))
    if rows.size:
        cols = np.flatnonzero(sharp.any(axis=0))
        top = max(0, min(top, int(rows[0]) - grow))
        bottom = min(sharp.shape[0], max(bottom, int(rows[-1]) + 1 + grow))
        left = max(0, min(left, int(cols[0]) - grow))
        right = min(sharp.shape[1], max(right, int(cols[-1]) + 1 + grow))
    return sharp[top:bottom, left:right], GelWindow((n, m), (pad - top, pad - left))


def smoothed_in_frame(sharp_at: Callable[[np.ndarray, np.ndarray], np.ndarray],
                      shape: tuple[int, int], sigma_px: float) -> np.ndarray:
    """The ``N × M`` frame ``shape`` of a sharp shape smoothed by a Gaussian of ``sigma_px``
    pixels over the gel beyond the frame too (``sharp_at`` as :func:`gel_window`)."""
    sharp, win = gel_window(sharp_at, shape, reach_px(sigma_px))
    return win.frame(smooth(sharp, sigma_px))
