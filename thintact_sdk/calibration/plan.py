"""The wizard's pattern sequence: dark, white, registration squares, every slit, validation.

Scenes are built lazily (at the paper's size the slits alone would be 2 GiB of float32).
Labels are unique and stable, so a resumed run finds what is already recorded.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from thintact_sdk.formats.profiles import Profile
from thintact_sdk.simulation.scenes import make_scene

DEFAULT_VALIDATION = ("gelsight:0", "gelsight:5", "usaf", "checker", "smooth_color")
"""Validation scenes (``name`` or ``name:index`` of :func:`thintact_sdk.simulation.scenes.make_scene`)."""

REGISTRATION_CORNERS = ("tl", "tr", "bl", "br")


@dataclass(frozen=True)
class Step:
    """One pattern to show and record.

    Attributes
    ----------
    label
        Unique label in the capture recording (also its file name stem).
    kind
        ``dark``, ``white``, ``registration``, ``hslit``, ``vslit`` or ``validation``.
    make
        Builds the ``N × M × 3`` float32 scene in [0, 1].
    """

    label: str
    kind: str
    make: Callable[[], np.ndarray]


def _const(n: int, m: int, value: float) -> Callable[[], np.ndarray]:
    return lambda: np.full((n, m, 3), value, np.float32)


def _row(n: int, m: int, i: int) -> Callable[[], np.ndarray]:
    def make() -> np.ndarray:
        x = np.zeros((n, m, 3), np.float32)
        x[i, :, :] = 1.0
        return x

    return make


def _col(n: int, m: int, j: int) -> Callable[[], np.ndarray]:
    def make() -> np.ndarray:
        x = np.zeros((n, m, 3), np.float32)
        x[:, j, :] = 1.0
        return x

    return make


def registration_scene(n: int, m: int, corner: str) -> np.ndarray:
    """A white square of a quarter of the area's size in one corner (``tl``, ``tr``, ``bl``, ``br``)."""
    x = np.zeros((n, m, 3), np.float32)
    h, w = max(1, n // 4), max(1, m // 4)
    r0 = 0 if corner[0] == "t" else n - h
    c0 = 0 if corner[1] == "l" else m - w
    x[r0 : r0 + h, c0 : c0 + w] = 1.0
    return x


def _corner(n: int, m: int, corner: str) -> Callable[[], np.ndarray]:
    return lambda: registration_scene(n, m, corner)


def _validation(n: int, m: int, spec: str) -> Callable[[], np.ndarray]:
    name, _, idx = spec.partition(":")
    index = int(idx) if idx else 0
    return lambda: make_scene(name, n, m, index).astype(np.float32)


def build_plan(profile: Profile, validation: tuple[str, ...] = DEFAULT_VALIDATION) -> list[Step]:
    """Every step of a calibration capture for ``profile``, in recording order.

    The white frame comes first after the dark frame because the exposure is set from it;
    registration squares come before the slit scan so a misplaced sensing area is caught
    before the long part.
    """
    n, m = profile.scene.rows, profile.scene.cols
    steps = [Step("dark", "dark", _const(n, m, 0.0)), Step("white", "white", _const(n, m, 1.0))]
    steps += [Step(f"reg_{c}", "registration", _corner(n, m, c)) for c in REGISTRATION_CORNERS]
    steps += [Step(f"hslit_{i:04d}", "hslit", _row(n, m, i)) for i in range(n)]
    steps += [Step(f"vslit_{j:04d}", "vslit", _col(n, m, j)) for j in range(m)]
    steps += [
        Step(f"val_{spec.replace(':', '_')}", "validation", _validation(n, m, spec))
        for spec in validation
    ]
    return steps
