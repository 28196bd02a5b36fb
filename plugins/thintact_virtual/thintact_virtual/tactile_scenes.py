"""The ``tactile`` scene source of the virtual camera: the tactile simulator's membrane.

Frame 0 of every cycle is the unloaded membrane (what a sensor takes as its no-contact
reference); frames 1 … :data:`PRESSES_PER_CYCLE` press a ball into the middle of the
membrane, ever deeper. Odd presses are pure normal loads; even presses add a tangential load
in partial slip (the elastic Cattaneo–Mindlin solution of
``thintact_sdk.algorithms.simulate_loaded_press``: the stuck centre moves the markers
rigidly, the rim slips and lags), each with less of the contact stuck than the one before.

Depths are those of the calibration ball sized to the field
(``thintact_sdk.algorithms.ball_radius_for_field``: 0.3-0.9 mm on virtual-finger). The ball
is that one, or a flatter one where the markers need it: slip is read from the markers inside
the loaded core (the region deeper than half the peak depth, radius √(R·d) for a ball of
radius R at depth d), and a disc narrower than the marker pitch p may hold fewer than two
markers, so the ball's radius is at least p²/d at the shallowest press (7.5 mm on
virtual-finger, 1.5 mm pitch), when such a ball's contact still fits the field (else the
calibration ball: a field that small cannot show slip at that pitch).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thintact_sdk.algorithms import (
    Elastomer,
    Sphere,
    TactileSimulator,
    ball_radius_for_field,
    simulate_loaded_press,
)
from thintact_sdk.plugin_support import Profile

TACTILE_SCENE = "tactile"
"""Scene name selecting this source in the camera's ``scenes`` setting."""
PRESSES_PER_CYCLE = 8
"""Pressed frames after each unloaded one."""
CYCLE = PRESSES_PER_CYCLE + 1
_DEPTH_RADII = (0.2, 0.6)
"""First and last press depth of a cycle, in calibration-ball radii (0.3-0.9 mm for 1.5 mm)."""
_STICK_FRACTIONS = (0.8, 0.4)
"""d*/d of the first and last sheared press (1: stuck, 0: sliding)."""
SHEAR_DIRECTION_RAD = float(np.arctan2(0.5, 1.0))
"""Direction of the tangential load (atan2(y, x) in the scene frame)."""
_FIT_SHARE = 2.0 / 3.0
"""The deepest press's contact radius stays within this share of the field's shorter half side."""


@dataclass(frozen=True)
class CyclePress:
    """One press of the cycle: ball radius and depth (mm), d*/d (1.0: no tangential load)."""

    ball_radius_mm: float
    depth_mm: float
    stick_fraction: float

    @property
    def sheared(self) -> bool:
        """True when the press carries a tangential load."""
        return self.stick_fraction < 1.0


def cycle_ball_radius_mm(profile: Profile) -> float:
    """Radius (mm) of the cycle's ball on ``profile`` (see the module docstring)."""
    params = TactileSimulator.for_profile(profile).params
    calibration = ball_radius_for_field(profile)
    shallow, deep = (calibration * r for r in _DEPTH_RADII)
    pitch = float(params.marker_pitch_mm or 0.0)
    needed = pitch**2 / shallow
    half = min(params.rows, params.cols) / 2 * params.mm_per_px
    fits = (_FIT_SHARE * half) ** 2 / (2.0 * deep)  # √(2·R·d) is the touching radius
    return max(calibration, needed) if needed <= fits else calibration


def cycle_press(profile: Profile, index: int) -> CyclePress | None:
    """The press shown at ``index`` of the cycle (None: the unloaded frame)."""
    k = index % CYCLE
    if k == 0:
        return None
    calibration = ball_radius_for_field(profile)
    t = (k - 1) / max(PRESSES_PER_CYCLE - 1, 1)
    depth = calibration * (_DEPTH_RADII[0] + t * (_DEPTH_RADII[1] - _DEPTH_RADII[0]))
    stick = 1.0
    if k % 2 == 0:
        sheared = PRESSES_PER_CYCLE // 2
        j = (k // 2 - 1) / max(sheared - 1, 1)
        stick = _STICK_FRACTIONS[0] + j * (_STICK_FRACTIONS[1] - _STICK_FRACTIONS[0])
    return CyclePress(cycle_ball_radius_mm(profile), depth, stick)


def tactile_scene(profile: Profile, index: int) -> np.ndarray:
    """Membrane image ``index`` of the cycle (0 unloaded, then presses).

    Returns
    -------
    numpy.ndarray
        ``N × M × 3`` float32 scene in [0, 1] (display units).
    """
    sim = TactileSimulator.for_profile(profile)
    press = cycle_press(profile, index)
    if press is None:
        return sim.flat().scene
    loaded = simulate_loaded_press(
        sim, Elastomer.from_profile(profile), Sphere(press.ball_radius_mm), press.depth_mm,
        (0.0, 0.0), 0.0, SHEAR_DIRECTION_RAD, press.stick_fraction)
    return loaded.scene.scene
