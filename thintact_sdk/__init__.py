"""ThinTact SDK: lensless vision-based tactile sensors in Python.

Robot programs::

    import thintact_sdk as thintact
    with thintact.open("virtual-mini") as sensor:
        frame = sensor.read()          # TactileFrame: image, depth_mm, markers, contact
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from thintact_sdk.errors import ThinTactError
from thintact_sdk.hookspecs import Component, hookimpl
from thintact_sdk.profile import Profile, load_profile

__version__ = "0.1.0"

if TYPE_CHECKING:
    from thintact_sdk.sensor import Sensor

__all__ = ["Component", "Profile", "ThinTactError", "__version__", "hookimpl", "load_profile", "open"]


def open(profile: str | Profile, **options: Any) -> Sensor:  # noqa: A001 - the public verb
    """Open a sensor by profile name, profile file or :class:`Profile`.

    Returns an opened :class:`thintact_sdk.sensor.Sensor`; use it as a context manager.
    """
    from thintact_sdk.sensor import Sensor

    sensor = Sensor(load_profile(profile), **options)
    sensor.open()
    return sensor
