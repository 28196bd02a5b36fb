"""A large device's rotated-mask kernel as the kernels of windows of its sensor.

The rotated kernel (:mod:`~thintact_sdk.simulation.rotated`) tabulates, per axis, the mask
profile displaced over the range the rotation sweeps across the device, for every (sensor
pixel, scene pixel) pair of that axis. That family grows with the sensor's extent twice:
through its number of pixels and through the displacement range. A sensor pixel's value
depends only on its own row and column, so the kernel of a window of the sensor is the same
computation on fewer sensor pixels, offset from the optical axis
(:attr:`~thintact_sdk.simulation.params.KernelParams.row_offset_px`): each window's family
covers only its own pixels and its own, shorter displacement range. The device's output is
the windows' outputs side by side, the same numbers as one whole-sensor build (to the
compression tolerance), at a fraction of the memory.

Every window shares the whole device's radiometric expansion (it spans every window's
offsets). Windows make builds possible that the whole build refuses (the 8×-binned paper
device rotated by 0.3°, the full 1024 × 1280 sensor at 0.05°) and shorten those it takes;
the times are in ``docs/simulator.md`` and docs/benchmarks.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from thintact_sdk.errors import KernelSizeError, ThinTactError
from thintact_sdk.simulation.params import KernelParams
from thintact_sdk.simulation.separable import SeparableKernel

WINDOW_FAMILY_BYTES = 160 * 1024**2
"""Largest displacement family (one axis) of one window: the sensor is cut into windows
until each one's family is at most this (a window of the 8×-binned paper device: 105 MiB)."""

TILED_FAMILY_BYTES = 4 * 1024**3
"""Largest sum of the windows' families a tiled build takes on (the work of the build grows
with it: the 8×-binned paper device's 16 windows sum to 1.7 GiB; the full 1024 × 1280
sensor would need about 256 windows and 35 GiB)."""

MAX_WINDOWS_PER_AXIS = 16
"""Most windows along one sensor axis."""


@dataclass(frozen=True)
class SensorWindow:
    """Sensor rows ``row0:row1`` and columns ``col0:col1`` of a device, with their kernel."""

    row0: int
    row1: int
    col0: int
    col1: int
    kernel: SeparableKernel


@dataclass
class TiledKernel:
    """The imaging kernel of a device as the kernels of windows covering its sensor.

    Attributes
    ----------
    windows
        Non-overlapping windows covering the ``rows × cols`` sensor exactly.
    rows, cols
        Sensor size, pixels.
    info
        ``{"windows", "terms" (summed over the windows), "rank", ...}``.
    """

    windows: list[SensorWindow]
    rows: int
    cols: int
    info: dict[str, float] = field(default_factory=dict)

    def apply(self, scenes: np.ndarray, dtype: str = "float64") -> np.ndarray:
        """``F × N × M × C`` scenes → ``F × R × S × C`` float64 signal (simulator units),
        each window's rows and columns from its own kernel; ``dtype`` is the arithmetic
        precision (:meth:`~thintact_sdk.simulation.separable.SeparableKernel.apply`)."""
        f, _, _, c = scenes.shape
        out = np.empty((f, self.rows, self.cols, c))
        for w in self.windows:
            out[:, w.row0 : w.row1, w.col0 : w.col1] = w.kernel.apply(scenes, dtype)
        return out


@dataclass
class StreamedTiledKernel:
    """A tiled kernel whose windows are built at each :meth:`apply` and dropped after it:
    the memory of one window at a time, the build's time at every call. For rendering a
    large rotated device once (a recording at the paper's size), where keeping every
    window's terms would not fit; :class:`TiledKernel` for anything evaluated repeatedly.

    Attributes
    ----------
    kp
        The whole device's kernel parameters.
    spans
        ``(row0, row1, col0, col1)`` windows covering the sensor (:func:`plan_windows`).
    build_window
        Kernel of one window's parameters (:func:`window_params`).
    progress
        Called as ``progress(done, total)`` after each window of an apply.
    """

    kp: KernelParams
    spans: list[tuple[int, int, int, int]]
    build_window: Callable[[KernelParams], SeparableKernel]
    progress: Callable[[int, int], None] | None = None
    info: dict[str, float] = field(default_factory=dict)

    @property
    def rows(self) -> int:
        """Sensor rows, pixels."""
        return self.kp.rows

    @property
    def cols(self) -> int:
        """Sensor columns, pixels."""
        return self.kp.cols

    def apply(self, scenes: np.ndarray, dtype: str = "float64") -> np.ndarray:
        """As :meth:`TiledKernel.apply`, building each window's kernel on the way."""
        f, _, _, c = scenes.shape
        out = np.empty((f, self.rows, self.cols, c))
        terms = 0.0
        pieces = 0
        for i, span in enumerate(self.spans):
            for w in build_window_pieces(self.kp, span, self.build_window):
                out[:, w.row0 : w.row1, w.col0 : w.col1] = w.kernel.apply(scenes, dtype)
                terms += w.kernel.info.get("terms", 0.0)
                pieces += 1
            if self.progress is not None:
                self.progress(i + 1, len(self.spans))
        self.info = {"windows": float(pieces), "terms": terms, "streamed": 1.0}
        return out


MAX_SPLITS = 3
"""A window whose kernel is refused for its size is cut into quadrants at most this many
times over (:func:`build_window_pieces`)."""


def build_window_pieces(kp: KernelParams, span: tuple[int, int, int, int],
                        build_window: Callable[[KernelParams], SeparableKernel],
                        depth: int = 0) -> list[SensorWindow]:
    """The kernel of sensor window ``span`` of ``kp``, as one window or, where its build is
    refused for its size (:class:`~thintact_sdk.errors.KernelSizeError`: the planner bounds
    the displacement families, but a rotated window's separable terms before compression
    grow with its rows and columns times its family ranks, e.g. 2.0 GiB for a 114×116 window
    of the paper's sensor at 0.2°), as the kernels of its quadrants, recursively (at most
    :data:`MAX_SPLITS` times; then the refusal stands)."""
    r0, r1, c0, c1 = span
    try:
        return [SensorWindow(r0, r1, c0, c1, build_window(window_params(kp, r0, r1, c0, c1)))]
    except KernelSizeError:
        if depth >= MAX_SPLITS or (r1 - r0 < 2 and c1 - c0 < 2):
            raise
    rm, cm = (r0 + r1) // 2, (c0 + c1) // 2
    rows = [(r0, rm), (rm, r1)] if r1 - r0 >= 2 else [(r0, r1)]
    cols = [(c0, cm), (cm, c1)] if c1 - c0 >= 2 else [(c0, c1)]
    return [w for a, b in rows for c, d in cols for w in build_window_pieces(kp, (a, b, c, d), build_window, depth + 1)]


def window_params(kp: KernelParams, row0: int, row1: int, col0: int, col1: int) -> KernelParams:
    """The kernel parameters of sensor rows ``row0:row1``, columns ``col0:col1`` of ``kp``'s
    (centred) sensor: the same optics, fewer sensor pixels, centre off the axis."""
    if not (0 <= row0 < row1 <= kp.rows and 0 <= col0 < col1 <= kp.cols):
        raise ThinTactError(f"window rows {row0}:{row1}, cols {col0}:{col1} is not inside the "
                            f"{kp.rows}×{kp.cols} sensor")
    return replace(kp, rows=row1 - row0, cols=col1 - col0,
                   row_offset_px=kp.row_offset_px + (row0 + row1) / 2 - kp.rows / 2,
                   col_offset_px=kp.col_offset_px + (col0 + col1) / 2 - kp.cols / 2)


def spread_windows(spans: list[tuple[int, int, int, int]], n: int) -> list[tuple[int, int, int, int]]:
    """``n`` of ``spans`` (all when fewer) spread evenly over the list: a row-major window plan
    gives windows at its start, middle and end, so across the sensor's rows and columns,
    centre and edges."""
    picks = sorted({int(round(i)) for i in np.linspace(0, len(spans) - 1, min(n, len(spans)))})
    return [spans[i] for i in picks]


def split_axis(n: int, parts: int) -> list[tuple[int, int]]:
    """``parts`` contiguous ``(start, stop)`` ranges of ``0..n`` as equal as integers allow."""
    edges = [round(i * n / parts) for i in range(parts + 1)]
    return list(zip(edges[:-1], edges[1:], strict=True))


def plan_windows(kp: KernelParams, family_bytes: Callable[[KernelParams], float],
                 window_limit: float = WINDOW_FAMILY_BYTES,
                 total_limit: float = TILED_FAMILY_BYTES) -> list[tuple[int, int, int, int]]:
    """The fewest windows (``(row0, row1, col0, col1)``, row-major) whose families are each
    at most ``window_limit``: the axis with more pixels per window is cut once more until
    they are.

    Raises
    ------
    ThinTactError
        When even :data:`MAX_WINDOWS_PER_AXIS` windows per axis leave a family above
        ``window_limit``, or the windows' families sum above ``total_limit`` (the build
        would take too long: say so before any of it starts).
    """
    n_r = n_c = 1
    while True:
        spans = [(r0, r1, c0, c1) for r0, r1 in split_axis(kp.rows, n_r) for c0, c1 in split_axis(kp.cols, n_c)]
        sizes = [family_bytes(window_params(kp, *w)) for w in spans]
        if max(sizes) <= window_limit:
            break
        if n_r >= MAX_WINDOWS_PER_AXIS and n_c >= MAX_WINDOWS_PER_AXIS:
            raise ThinTactError(
                f"physics: a mask rotated by {kp.angle_deg:g}° on this device ({kp.rows}×{kp.cols} "
                f"sensor, {kp.scene_rows}×{kp.scene_cols} scene) needs displacement families of "
                f"{max(sizes) / 1024**2:.0f} MiB even in windows of "
                f"{math.ceil(kp.rows / n_r)}×{math.ceil(kp.cols / n_c)} sensor pixels "
                f"(limit {window_limit / 1024**2:.0f} MiB)")
        if (kp.rows / n_r >= kp.cols / n_c and n_r < MAX_WINDOWS_PER_AXIS) or n_c >= MAX_WINDOWS_PER_AXIS:
            n_r += 1
        else:
            n_c += 1
    total = float(sum(sizes))
    if total > total_limit:
        raise ThinTactError(
            f"physics: a mask rotated by {kp.angle_deg:g}° on this device ({kp.rows}×{kp.cols} "
            f"sensor, {kp.scene_rows}×{kp.scene_cols} scene) needs {len(spans)} sensor windows whose "
            f"displacement families sum to {total / 1024**3:.1f} GiB (limit "
            f"{total_limit / 1024**3:.1f} GiB: the build's time grows with their size): bin the "
            "sensor (e.g. the diagnosis's binned profile) to simulate it")
    return spans


def build_tiled_kernel(kp: KernelParams, spans: list[tuple[int, int, int, int]],
                       build_window: Callable[[KernelParams], SeparableKernel],
                       progress: Callable[[int, int], None] | None = None) -> TiledKernel:
    """Build each window's kernel with ``build_window`` (one after another: each window's
    build uses the build threads itself) and put them side by side.

    Parameters
    ----------
    kp
        The whole device's kernel parameters.
    spans
        ``(row0, row1, col0, col1)`` windows covering the sensor (:func:`plan_windows`).
    build_window
        Kernel of one window's parameters (:func:`window_params`).
    progress
        Called as ``progress(done, total)`` after each window.
    """
    windows: list[SensorWindow] = []
    terms = 0.0
    info: dict[str, float] = {}
    for i, span in enumerate(spans):
        for w in build_window_pieces(kp, span, build_window):
            windows.append(w)
            terms += w.kernel.info.get("terms", float(max(len(t) for t in w.kernel.terms)))
            info = {k: v for k, v in w.kernel.info.items() if k != "terms"}
        if progress is not None:
            progress(i + 1, len(spans))
    return TiledKernel(windows, kp.rows, kp.cols, {**info, "windows": float(len(windows)), "terms": terms})
