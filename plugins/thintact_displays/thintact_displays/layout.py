"""Where a scene lands on a panel: origin, pixel block size, 8-bit values.

The monitor pixel is the scene pixel (paper: 31.5 um on a 5.5" 3840×2160 panel). When the
profile's scene pitch is an integer multiple of the panel pitch, each scene pixel becomes
a ``k × k`` block of panel pixels; any other ratio is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thintact_sdk.errors import DeviceError, InvalidShapeError, ProfileError
from thintact_sdk.plugin_support import Profile


@dataclass(frozen=True)
class PanelLayout:
    """Placement of the sensing area on the panel.

    Attributes
    ----------
    origin_x_px, origin_y_px
        Panel pixel of the scene's top-left corner.
    block_px
        Panel pixels per scene pixel along each axis.
    scene_rows, scene_cols
        N, M.
    """

    origin_x_px: int
    origin_y_px: int
    block_px: int
    scene_rows: int
    scene_cols: int

    @property
    def width_px(self) -> int:
        """Width of the sensing area on the panel (panel pixels)."""
        return self.scene_cols * self.block_px

    @property
    def height_px(self) -> int:
        """Height of the sensing area on the panel (panel pixels)."""
        return self.scene_rows * self.block_px

    def check_fits(self, panel_width_px: int, panel_height_px: int) -> None:
        """Raise :class:`DeviceError` unless the sensing area lies inside the panel."""
        right = self.origin_x_px + self.width_px
        bottom = self.origin_y_px + self.height_px
        if self.origin_x_px < 0 or self.origin_y_px < 0 or right > panel_width_px or bottom > panel_height_px:
            raise DeviceError(
                f"the sensing area ({self.width_px}×{self.height_px} px at origin "
                f"({self.origin_x_px}, {self.origin_y_px})) does not fit the "
                f"{panel_width_px}×{panel_height_px} panel; fix display.origin_px in the profile"
            )


def panel_layout(profile: Profile) -> PanelLayout:
    """The layout the profile's ``display`` section describes (defaults when absent)."""
    disp = profile.display
    origin = disp.origin_px if disp is not None else (0, 0)
    panel_pitch = disp.pixel_pitch_um if disp is not None else profile.scene.pixel_pitch_um
    ratio = profile.scene.pixel_pitch_um / panel_pitch
    block = int(round(ratio))
    if block < 1 or abs(ratio - block) > 0.01 * ratio:
        raise ProfileError(
            f"profile {profile.name!r}: scene.pixel_pitch_um {profile.scene.pixel_pitch_um} is not "
            f"an integer multiple of display.pixel_pitch_um {panel_pitch}; the monitor pixel must "
            "be the scene pixel (or an integer block of them)"
        )
    return PanelLayout(int(origin[0]), int(origin[1]), block, profile.scene.rows, profile.scene.cols)


def scene_to_rgb8(scene: np.ndarray, block_px: int = 1) -> np.ndarray:
    """Scene values in [0, 1] → panel ``(N·k) × (M·k) × 3`` uint8 (rounded, clipped).

    Parameters
    ----------
    scene
        ``N × M × 3`` (or ``N × M``, shown grey) display values.
    block_px
        k, panel pixels per scene pixel.
    """
    x = np.asarray(scene, dtype=np.float64)
    if x.ndim == 2:
        x = np.repeat(x[..., None], 3, axis=2)
    if x.ndim != 3 or x.shape[2] != 3:
        raise InvalidShapeError(f"a scene is N×M×3, got shape {np.shape(scene)}")
    rgb = np.rint(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)
    if block_px > 1:
        rgb = np.repeat(np.repeat(rgb, block_px, axis=0), block_px, axis=1)
    return rgb


def check_scene_shape(scene: np.ndarray, profile: Profile) -> None:
    """Raise ValueError unless ``scene`` is the profile's ``N × M × 3``."""
    want = (profile.scene.rows, profile.scene.cols, 3)
    if tuple(np.shape(scene)) != want:
        raise InvalidShapeError(f"scene must be {want[0]}×{want[1]}×3 for profile {profile.name!r}, got {np.shape(scene)}")
