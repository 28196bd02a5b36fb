"""``thintact view``: a live sensor in the browser, served on 127.0.0.1 (docs/viewer.md).

:class:`LiveView` runs a sensor and renders its dashboard (raw measurement,
reconstruction, depth, marker arrows, contact and shear, rates); :class:`ViewerServer`
serves it as a web page.
"""

from __future__ import annotations

from thintact_sdk.apps.viewer.frame_loop import LiveView
from thintact_sdk.apps.viewer.server import ViewerServer

__all__ = ["LiveView", "ViewerServer"]
