"""A full-screen pygame (SDL2) window on the calibration LCD.

The window covers display ``profile.display.display_index`` without borders or cursor; the
scene is drawn at ``profile.display.origin_px`` (panel pixels), black everywhere else, and
shown with a buffer flip. Settings:

``display_index``
    Overrides the profile's display.
``windowed``
    ``[width, height]``: an ordinary window instead of full screen (for development).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from thintact_displays.layout import PanelLayout, check_scene_shape, panel_layout, scene_to_rgb8
from thintact_sdk.errors import DeviceError, DeviceNotFoundError, PluginError
from thintact_sdk.interfaces import Display
from thintact_sdk.plugin_support import Profile


class PygameDisplay(Display):
    """Draws calibration scenes on an LCD through pygame.

    Parameters
    ----------
    profile
        Device profile; its ``display`` section gives the display index, origin and pitch.
    settings
        See the module docstring.
    """

    name = "pygame"

    def __init__(self, profile: Profile, settings: dict[str, Any]) -> None:
        self.profile = profile
        self.layout: PanelLayout = panel_layout(profile)
        disp = profile.display
        self.display_index = int(settings.get("display_index", disp.display_index if disp else 0))
        windowed = settings.get("windowed")
        self.windowed: tuple[int, int] | None = (int(windowed[0]), int(windowed[1])) if windowed else None
        self._pg: Any = None
        self._screen: Any = None
        self.panel_size_px: tuple[int, int] = (0, 0)

    def open(self) -> None:
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        try:
            import pygame
        except ImportError:
            raise PluginError("the pygame display needs pygame: pip install pygame") from None
        try:
            pygame.display.init()
        except pygame.error as err:
            raise DeviceNotFoundError(
                f"cannot open a display for the calibration pattern ({err}); is an X server "
                "running and DISPLAY set?"
            ) from None
        count = pygame.display.get_num_displays()
        if self.display_index >= count:
            pygame.display.quit()
            raise DeviceNotFoundError(
                f"display {self.display_index} not found ({count} display(s) connected); set "
                "display.display_index in the profile"
            )
        if self.windowed is not None:
            size = self.windowed
            flags = pygame.NOFRAME
        else:
            sizes = pygame.display.get_desktop_sizes()
            size = sizes[self.display_index]
            flags = pygame.FULLSCREEN | pygame.NOFRAME
        try:
            self.layout.check_fits(*size)
        except DeviceError:
            pygame.display.quit()
            raise
        self._screen = pygame.display.set_mode(size, flags, display=self.display_index)
        pygame.display.set_caption("thintact calibration")
        pygame.mouse.set_visible(False)
        self.panel_size_px = (int(size[0]), int(size[1]))
        self._pg = pygame
        self._screen.fill((0, 0, 0))
        pygame.display.flip()

    def close(self) -> None:
        if self._pg is not None:
            self._pg.display.quit()
            self._pg = None
            self._screen = None

    def show(self, scene: np.ndarray) -> None:
        """Draw ``scene`` (``N × M × 3`` in [0, 1], 8-bit on the panel) and flip."""
        if self._pg is None:
            raise DeviceError("the pygame display is not open")
        check_scene_shape(scene, self.profile)
        pg = self._pg
        pg.event.pump()
        rgb = scene_to_rgb8(scene, self.layout.block_px)
        surface = pg.surfarray.make_surface(np.ascontiguousarray(rgb.transpose(1, 0, 2)))
        self._screen.fill((0, 0, 0))
        self._screen.blit(surface, (self.layout.origin_x_px, self.layout.origin_y_px))
        pg.display.flip()
