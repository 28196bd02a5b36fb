"""What a recorded scene is, found from the scene array itself (labels are not trusted).

Per channel, a scene is *dark* (all zero), a *horizontal slit* (exactly one scene row
lit), a *vertical slit* (exactly one column lit) or *other*. A single lit pixel is both a
row and a column and counts as *other* (it cannot tell P from Q).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Kind = Literal["dark", "hslit", "vslit", "other"]
ZERO_LEVEL = 1e-6
"""Display values at or below this are "off" (scenes are float32 in [0, 1])."""


@dataclass(frozen=True)
class ChannelRole:
    """Role of one channel of a scene.

    Attributes
    ----------
    kind
        ``dark``, ``hslit``, ``vslit`` or ``other``.
    index
        The lit row (``hslit``) or column (``vslit``); ``-1`` otherwise.
    profile
        The slit's values along its length (``M`` for a row, ``N`` for a column), float64;
        ``None`` unless a slit.
    """

    kind: Kind
    index: int = -1
    profile: np.ndarray | None = None


def classify_channel(scene: np.ndarray, zero_level: float = ZERO_LEVEL) -> ChannelRole:
    """Role of one ``N × M`` channel of a scene."""
    lit = np.abs(np.asarray(scene, dtype=np.float64)) > zero_level
    if not lit.any():
        return ChannelRole("dark")
    rows = np.flatnonzero(lit.any(axis=1))
    cols = np.flatnonzero(lit.any(axis=0))
    if len(rows) == 1 and len(cols) > 1:
        return ChannelRole("hslit", int(rows[0]), np.asarray(scene[rows[0], :], np.float64).copy())
    if len(cols) == 1 and len(rows) > 1:
        return ChannelRole("vslit", int(cols[0]), np.asarray(scene[:, cols[0]], np.float64).copy())
    return ChannelRole("other")


def classify_scene(scene: np.ndarray, zero_level: float = ZERO_LEVEL) -> list[ChannelRole]:
    """Role of every channel of an ``N × M × C`` scene."""
    x = np.asarray(scene)
    if x.ndim == 2:
        x = x[..., None]
    return [classify_channel(x[..., c], zero_level) for c in range(x.shape[2])]


def is_dark(roles: list[ChannelRole]) -> bool:
    """All channels off: a dark frame."""
    return all(r.kind == "dark" for r in roles)


def is_slit(roles: list[ChannelRole]) -> bool:
    """At least one channel is a slit and none is *other*."""
    return any(r.kind in ("hslit", "vslit") for r in roles) and not any(r.kind == "other" for r in roles)


def roles_for_channels(roles: list[ChannelRole], channels: int) -> list[ChannelRole]:
    """A scene's per-channel roles as the device's channels: an RGB scene's G role serves
    both green planes of a device keeping the Bayer sites apart (R, Gr, Gb, B); otherwise
    unchanged (a monochrome device takes the first channel's role, as before)."""
    if channels == 4 and len(roles) == 3:
        return [roles[0], roles[1], roles[1], roles[2]]
    return roles
