"""The fitted model checked on windows of the unbinned sensor, where the whole sensor's
kernel is refused.

A binned diagnosis ends with the fitted model evaluated once on the unbinned recording
(:func:`~thintact_sdk.diagnosis.imaging.binning.full_size_check`): structure finer than a block that
the binned fit missed shows there as χ²/dof above 1. A mask rotated by more than about
0.05° on the paper's device has no whole-sensor kernel within the memory a kept build may
take (0.1°: 48 windows, 6.6 GiB of families), so that check was not evaluated at all. Each
window of the sensor, though, builds in seconds
(:meth:`~thintact_sdk.simulation.simulator.Simulator.linear_window`), so the same contract
statistics are computed on a few windows spread over the window plan (centre and edges), on
a few frames: each window is a small recording of its own, with its own gains and
closed-form terms refitted (as the full-size check refits them), the effects' parameters as
fitted. A window's own gains can absorb an error that is smooth over the window, but such
an error is as plain on the binned data, where the fit was made with every pixel; what the
windows add is structure finer than a block, which no gain absorbs. Effects whose pixels
read beyond themselves (a sensor blur, veiling glare: ``reads_beyond_pixel``) cannot be
evaluated on a window alone; the check then says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from thintact_sdk.diagnosis.imaging.coarse_angle import FINE_FRAMES, FINE_WINDOWS
from thintact_sdk.diagnosis.imaging.forward_model import (
    DiagnosisModel,
    Values,
    contract_fit,
    evaluate_self_weighted,
    optical_physics,
)
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData, subset_frames
from thintact_sdk.diagnosis.imaging.stats import FitStats, default_variance_fn
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.simulation.effects import window_blocker

PLAIN_GRID = (6, 8)
"""Windows (rows × columns of the sensor) when the fitted kernel is not a rotated one (it
has no window plan of its own), at most: each keeps :data:`MIN_WINDOW_SIDE` pixels a side."""

MIN_WINDOW_SIDE = 32
"""Sensor pixels a side of a plain grid's window at least: each window refits its own gains,
which would absorb more than fine structure in much smaller ones."""


@dataclass(frozen=True)
class WindowCheck:
    """What :func:`window_check` found (``report.json`` ``full_size.windows``).

    Attributes
    ----------
    stats
        CONTRACTS §6 statistics over every unsaturated value of the windows' frames (None
        when not evaluated).
    where
        The windows and frames, in words.
    note
        Why it was not evaluated (empty when it was).
    """

    stats: FitStats | None
    where: str = ""
    note: str = ""

    def excess_z(self) -> float:
        """χ² above its noise-only expectation, in its standard deviations (``√(2n)``)."""
        if self.stats is None or self.stats.n_pixels == 0:
            return float("nan")
        return (self.stats.chi2_per_dof - 1.0) * math.sqrt(self.stats.n_pixels / 2.0)

    def to_json(self) -> dict[str, object]:
        """The check as ``report.json`` reports it."""
        if self.stats is None:
            return {"not_evaluated": self.note}
        return {"rms_dn": round(self.stats.rms_dn, 4), "chi2_per_dof": round(self.stats.chi2_per_dof, 4),
                "excess_z": round(self.excess_z(), 2), "n_values": self.stats.n_pixels, "where": self.where}


def window_check(data: DiagnosisData, values: Values, sys_frac: float = 1e-3,
                 n_windows: int = FINE_WINDOWS, n_frames: int = FINE_FRAMES) -> WindowCheck:
    """The fitted model ``values`` on ``n_windows`` windows of ``data``'s (unbinned) sensor
    and ``n_frames`` of its frames.

    Returns
    -------
    WindowCheck
        The contract statistics pooled over the windows, or why they could not be computed.
    """
    from thintact_sdk.simulation.effects import resolve_physics
    from thintact_sdk.simulation.params import kernel_params
    from thintact_sdk.simulation.simulator import Simulator, streamed_rotated_kernel
    from thintact_sdk.simulation.tiled import split_axis, spread_windows

    prof = data.profile
    blocker = window_blocker([*prof.physics, *values])
    if blocker is not None:
        return WindowCheck(None, note=blocker)
    sub = subset_frames(data, n_frames)
    phys = optical_physics(prof, values)
    kp = kernel_params(prof.with_physics(phys), resolve_physics(phys))
    try:
        spans = streamed_rotated_kernel(kp).spans
    except ThinTactError:  # not a rotated kernel: a plain grid of windows
        parts_r = max(1, min(PLAIN_GRID[0], kp.rows // MIN_WINDOW_SIDE))
        parts_c = max(1, min(PLAIN_GRID[1], kp.cols // MIN_WINDOW_SIDE))
        spans = [(r0, r1, c0, c1) for r0, r1 in split_axis(kp.rows, parts_r) for c0, c1 in split_axis(kp.cols, parts_c)]
    picked = spread_windows(spans, n_windows)
    parts: list[FitStats] = []
    try:
        for span in picked:
            r0, r1, c0, c1 = span

            def simulate(profile: Profile, scenes: np.ndarray, span: tuple[int, int, int, int] = span) -> np.ndarray:
                return Simulator(profile, precision="float32").linear_window(scenes, span)

            window = DiagnosisData(prof, sub.labels, sub.scenes, sub.measured_dn[:, r0:r1, c0:c1])
            model = DiagnosisModel(window, simulate, default_variance_fn(), sys_frac=sys_frac, cache_size=1)
            parts.append(contract_fit(model, evaluate_self_weighted(model, values).pred_dn, values)[2])
    except ThinTactError as err:
        return WindowCheck(None, note=str(err))
    where = (f"{len(picked)} of {len(spans)} windows of the unbinned sensor ({sum(p.n_pixels for p in parts)} "
             f"values of {sub.n_frames} frames), each window with its own gains")
    return WindowCheck(_pooled(parts), where)


def _pooled(parts: list[FitStats]) -> FitStats:
    """The statistics of several disjoint sets of values as one set."""
    n = sum(p.n_pixels for p in parts)
    if n == 0:
        return FitStats(float("nan"), float("nan"), float("nan"), 0)

    def mean(values: list[float]) -> float:
        return sum(v * p.n_pixels for v, p in zip(values, parts, strict=True) if p.n_pixels) / n

    return FitStats(rms_dn=math.sqrt(mean([p.rms_dn**2 for p in parts])),
                    chi2_per_dof=mean([p.chi2_per_dof for p in parts]),
                    noise_rms_dn=math.sqrt(mean([p.noise_rms_dn**2 for p in parts])), n_pixels=n)
