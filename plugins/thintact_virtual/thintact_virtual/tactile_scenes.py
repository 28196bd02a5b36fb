"""The ``tactile`` scene source of the virtual camera: the tactile simulator's membrane.

Frame 0 of every cycle is the unloaded membrane (what a sensor takes as its no-contact
reference); frames 1 … :data:`PRESSES_PER_CYCLE` press the calibration ball (sized to the
field, :func:`thintact_sdk.tactile.calibration.ball_radius_for_field`) into the middle of the
membrane, ever deeper and with a growing sideways shear, so the markers move.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.algorithms import Sphere, TactileSimulator, ball_radius_for_field
from thintact_sdk.profile import Profile

TACTILE_SCENE = "tactile"
"""Scene name selecting this source in the camera's ``scenes`` setting."""
PRESSES_PER_CYCLE = 8
"""Pressed frames after each unloaded one."""
CYCLE = PRESSES_PER_CYCLE + 1
_DEPTH_RADII = (0.2, 0.6)
"""First and last press depth of a cycle, in ball radii (0.3-0.9 mm for the 1.5 mm ball)."""
_SHEAR_RADII = 0.1
"""Sideways shear of the last press of a cycle, in ball radii."""


def tactile_scene(profile: Profile, index: int) -> np.ndarray:
    """Membrane image ``index`` of the cycle (0 unloaded, then presses).

    Returns
    -------
    numpy.ndarray
        ``N × M × 3`` float32 scene in [0, 1] (display units).
    """
    sim = TactileSimulator.for_profile(profile)
    k = index % CYCLE
    if k == 0:
        return sim.flat().scene
    radius = ball_radius_for_field(profile)
    t = (k - 1) / max(PRESSES_PER_CYCLE - 1, 1)
    depth = radius * (_DEPTH_RADII[0] + t * (_DEPTH_RADII[1] - _DEPTH_RADII[0]))
    shear = radius * _SHEAR_RADII * t
    return sim.press(Sphere(radius), depth, (0.0, 0.0), shear_mm=(shear, 0.5 * shear)).scene
