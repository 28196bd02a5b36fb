"""Diagnose a press pack as ``thintact diagnose-tactile`` does: one call, the command's report.

:func:`diagnose_tactile_pack` reads the pack (or the directory holding one), chooses the
presses, runs :func:`~thintact_sdk.diagnosis.tactile.press_engine.diagnose_tactile` and refuses
a report with a non-finite χ²; the command only parses, prints and writes the outputs
(:func:`~thintact_sdk.diagnosis.tactile.report.write_tactile_outputs`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal

from thintact_sdk.diagnosis.tactile.press_data import load_presses
from thintact_sdk.diagnosis.tactile.press_engine import (
    TactileDiagnosis,
    TactileDiagnosisOptions,
    diagnose_tactile,
)
from thintact_sdk.errors import ThinTactError

PressChoice = Sequence[int] | Literal["all", "even"] | None
"""Which presses to use: ``None`` or ``"all"``, ``"even"`` (every second from the first), or
indices into the pack."""


def press_indices(choice: PressChoice, n: int) -> list[int] | None:
    """The presses ``choice`` names among ``n`` (``None``: all).

    Raises
    ------
    ThinTactError
        Fewer than 2 indices, or one outside ``0..n-1`` (named as ``--presses``).
    """
    if choice is None or choice == "all":
        return None
    idx = list(range(0, n, 2)) if choice == "even" else [int(i) for i in choice]
    if len(idx) < 2 or min(idx) < 0 or max(idx) >= n:
        raise ThinTactError(f"--presses: at least 2 indices in 0..{n - 1}")
    return idx


def diagnose_tactile_pack(
    pack: str | Path,
    ball_radius_mm: float,
    mm_per_px: float,
    presses: PressChoice = None,
    options: TactileDiagnosisOptions | None = None,
    *,
    progress: Callable[[str], None] | None = None,
    log: Callable[[str], None] | None = None,
) -> TactileDiagnosis:
    """Diagnose the tactile simulation against the ball presses of the pack ``pack`` (a
    ``.npz`` with ``imgs`` P×H×W×3 and ``f0``, or a directory holding one), as
    ``thintact diagnose-tactile`` does. ``ball_radius_mm``: the pressed ball's radius, mm;
    ``mm_per_px``: the image pixel size, mm. ``progress`` receives the engine's stage lines,
    ``log`` the line naming what was read.

    Raises
    ------
    ThinTactError
        A pack that cannot be read (named by file), presses that are not in it, or a
        non-finite χ² (no usable pixels).
    """
    real = load_presses(pack)
    n = len(real.images)
    idx = press_indices(presses, n)
    if log is not None:
        log(f"{n} presses of {real.reference.shape[1]}×{real.reference.shape[0]} px from {real.source}")
    d = diagnose_tactile(real, ball_radius_mm, mm_per_px, idx, options, progress=progress)
    for part in ("baseline", "final"):
        if not math.isfinite(d.report[part]["chi2_per_dof"]):
            raise ThinTactError("the diagnosis gave a non-finite χ² (no usable pixels?); nothing written")
    return d
