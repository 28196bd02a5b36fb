"""ThinTact SDK: lensless vision-based tactile sensors in Python.

Robot programs::

    import thintact_sdk as thintact
    with thintact.open("virtual-mini") as sensor:
        frame = sensor.read()          # TactileFrame: image, depth_mm, markers, contact
"""

from __future__ import annotations

import os as _os


def _tune_openblas() -> None:
    """numpy's bundled OpenBLAS does not recognise some AVX-512 CPUs and falls back to a
    slow kernel; name the core type before numpy loads (never overriding the user)."""
    if "OPENBLAS_CORETYPE" in _os.environ or "numpy" in __import__("sys").modules:
        return
    try:
        with __import__("builtins").open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("flags"):
                    flags = line.split()
                    if "avx512f" in flags and "avx512bw" in flags and "avx512vl" in flags:
                        _os.environ["OPENBLAS_CORETYPE"] = "SkylakeX"
                    return
    except OSError:
        return


_tune_openblas()

from typing import TYPE_CHECKING, Any  # noqa: E402

from thintact_sdk.errors import ThinTactError  # noqa: E402
from thintact_sdk.formats.profiles import Profile, load_profile  # noqa: E402
from thintact_sdk.hookspecs import Component, hookimpl  # noqa: E402

__version__ = "0.1.0"

if TYPE_CHECKING:
    from collections.abc import Sequence

    from thintact_sdk.device.group import SensorGroup
    from thintact_sdk.device.sensor import Sensor

__all__ = ["Component", "Profile", "ThinTactError", "__version__", "hookimpl", "load_profile", "open",
           "open_group"]


def open(profile: str | Profile, **options: Any) -> Sensor:  # noqa: A001 - the public verb
    """Open a sensor by profile name, profile file or :class:`Profile`.

    Returns an opened :class:`thintact_sdk.device.sensor.Sensor`; use it as a context manager.
    """
    from thintact_sdk.device.sensor import Sensor

    sensor = Sensor(load_profile(profile), **options)
    sensor.open()
    return sensor


def open_group(sensors: Sequence[str | Profile | Sensor], **options: Any) -> SensorGroup:
    """Open several sensors whose frames are paired by time (two fingers).

    Returns an opened :class:`thintact_sdk.device.group.SensorGroup`; see
    :func:`thintact_sdk.device.group.open_group` for the options and guarantees.
    """
    from thintact_sdk.device.group import open_group as _open_group

    return _open_group(sensors, **options)
