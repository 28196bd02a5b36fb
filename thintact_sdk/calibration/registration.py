"""Registration of the sensing area: does the sensor see the panel where the profile says?

Four white squares, one in each corner of the sensing area, are shown in turn. Under the
baseline physics a source's light lands mostly below it (cos⁴ fall-off), so the centroid of
each dark-subtracted measurement must sit in the matching corner direction: left squares
left of right squares, top squares above bottom squares. A wrong orientation (mirrored or
rotated panel) fails; so does a sensing area whose squares' mean centroid is far from the
sensor centre (``origin_px`` wrong), with the shift to apply.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from thintact_sdk.formats.profiles import Profile

MAX_OFFSET_FRACTION = 0.15
"""Largest accepted centroid offset, as a fraction of the sensor's width / height."""


@dataclass
class RegistrationResult:
    """Outcome of the registration check.

    Attributes
    ----------
    passed
        Orientation right and offset within :data:`MAX_OFFSET_FRACTION`.
    centroids_um
        ``{corner: (x_um, y_um)}`` signal centroid of each square on the sensor.
    offset_um
        Mean centroid relative to the sensor centre ``(x, y)`` in um.
    suggested_shift_px
        Panel pixels to add to ``display.origin_px`` to centre the area (rough: the
        centroid moves less than the source).
    problems
        Sentences naming what is wrong.
    """

    passed: bool
    centroids_um: dict[str, tuple[float, float]] = field(default_factory=dict)
    offset_um: tuple[float, float] = (0.0, 0.0)
    suggested_shift_px: tuple[int, int] = (0, 0)
    problems: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, object]:
        return {
            "passed": self.passed,
            "centroids_um": {k: list(v) for k, v in self.centroids_um.items()},
            "offset_um": list(self.offset_um),
            "suggested_shift_px": list(self.suggested_shift_px),
            "problems": list(self.problems),
        }


def centroid_um(signal: np.ndarray, pitch_um: float) -> tuple[float, float]:
    """Centroid ``(x, y)`` in um (CONTRACTS §1 axes) of an ``R × S (× C)`` signal ≥ 0."""
    s = np.asarray(signal, np.float64)
    if s.ndim == 3:
        s = s.sum(axis=2)
    s = np.clip(s, 0.0, None)
    total = s.sum()
    if total <= 0:
        return float("nan"), float("nan")
    r, c = s.shape
    y = ((np.arange(r) - (r - 1) / 2) * pitch_um) @ s.sum(axis=1) / total
    x = ((np.arange(c) - (c - 1) / 2) * pitch_um) @ s.sum(axis=0) / total
    return float(x), float(y)


def check_registration(signals: dict[str, np.ndarray], profile: Profile) -> RegistrationResult:
    """Check the four corner measurements (DN above dark, keys ``tl``, ``tr``, ``bl``, ``br``)."""
    pitch = profile.sensor.pixel_pitch_um
    cents = {k: centroid_um(v, pitch) for k, v in signals.items()}
    res = RegistrationResult(passed=True, centroids_um=cents)
    if any(not np.isfinite(v).all() for v in cents.values()):
        res.passed = False
        res.problems.append("a registration square gave no signal: is the display on and facing the sensor?")
        return res
    x = {k: v[0] for k, v in cents.items()}
    y = {k: v[1] for k, v in cents.items()}
    if not (x["tr"] > x["tl"] and x["br"] > x["bl"]):
        res.passed = False
        res.problems.append("left and right are swapped: the panel image is mirrored left-right")
    if not (y["bl"] > y["tl"] and y["br"] > y["tr"]):
        res.passed = False
        res.problems.append("top and bottom are swapped: the panel image is upside down")
    off = (float(np.mean(list(x.values()))), float(np.mean(list(y.values()))))
    res.offset_um = off
    width = profile.sensor.cols * pitch
    height = profile.sensor.rows * pitch
    panel_pitch = profile.display.pixel_pitch_um if profile.display is not None else profile.scene.pixel_pitch_um
    res.suggested_shift_px = (int(round(-off[0] / panel_pitch)), int(round(-off[1] / panel_pitch)))
    if abs(off[0]) > MAX_OFFSET_FRACTION * width or abs(off[1]) > MAX_OFFSET_FRACTION * height:
        res.passed = False
        res.problems.append(
            f"the sensing area is off-centre by ({off[0]:.0f}, {off[1]:.0f}) um on the sensor; move "
            f"display.origin_px by about {res.suggested_shift_px} panel pixels"
        )
    return res
