"""``identity``: imaging for lens-based sensors (DIGIT, GelSight Mini).

A camera with a lens already forms the membrane image, so there is nothing to decode: the
measurement (``R × S × 3`` DN above black, debayered or RGB as the camera gives it) is
scaled to display units and resampled (area average) to the profile's scene grid
``N × M``, after which the tactile pipeline (photometric stereo, markers, force) runs as it
does on a ThinTact's reconstruction.

Settings
--------
white_level_dn
    DN above black that maps to 1.0 (default: ``noise.saturation_dn − noise.black_level_dn``,
    i.e. 255 for an 8-bit UVC stream with black 0).
flip
    ``"none"`` (default), ``"horizontal"``, ``"vertical"`` or ``"both"``: mirror the image
    when the camera sees the gel from behind.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from thintact_sdk.errors import ProfileError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.interfaces import Decoder

FLIPS = {"none": None, "horizontal": 1, "vertical": 0, "both": -1}


class IdentityDecoder(Decoder):
    """Measurement → scene by scaling and area resampling (no reconstruction).

    Parameters
    ----------
    scene_shape
        ``(N, M)`` of the profile's scene grid.
    white_level_dn
        DN above black that becomes 1.0.
    flip
        A key of :data:`FLIPS`.
    """

    name = "identity"

    def __init__(self, scene_shape: tuple[int, int], white_level_dn: float,
                 flip: str = "none") -> None:
        if white_level_dn <= 0:
            raise ProfileError(f"identity decoder: white_level_dn must be > 0, got {white_level_dn}")
        if flip not in FLIPS:
            raise ProfileError(f"identity decoder: flip must be one of {', '.join(FLIPS)}, got {flip!r}")
        self.scene_shape = scene_shape
        self.white_level_dn = float(white_level_dn)
        self.flip = FLIPS[flip]

    def decode(self, frame: np.ndarray, black_level_dn: float = 0.0) -> np.ndarray:
        """``R × S × 3`` signal, DN above black (``input = "signal"``; ``black_level_dn`` is
        subtracted first where not 0) → ``N × M × 3`` float32 display units (≥ 0)."""
        img: np.ndarray = np.ascontiguousarray(frame, np.float32)
        if black_level_dn:
            img = img - np.float32(black_level_dn)
        img = img / np.float32(self.white_level_dn)
        n, m = self.scene_shape
        if img.shape[:2] != (n, m):
            shrinking = img.shape[0] >= n and img.shape[1] >= m
            img = cv2.resize(img, (m, n), interpolation=cv2.INTER_AREA if shrinking
                             else cv2.INTER_LINEAR)
        if self.flip is not None:
            img = cv2.flip(img, self.flip)
        return np.clip(img, 0.0, None).reshape(n, m, -1)


def make_identity(profile: Profile, settings: dict[str, Any]) -> IdentityDecoder:
    """Build the identity decoder for a lens-based ``profile``."""
    noise = profile.noise
    white = float(settings.get("white_level_dn", noise.saturation_dn - noise.black_level_dn))
    return IdentityDecoder((profile.scene.rows, profile.scene.cols), white,
                           str(settings.get("flip", "none")))
