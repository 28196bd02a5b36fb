"""Triggered acquisition through the GenICam SFNC trigger features.

``TriggerSelector`` (``FrameStart`` where offered), ``TriggerMode`` (``On``/``Off``),
``TriggerSource`` (``Software``, ``Line0``, ...) and the command ``TriggerSoftware``. A
device without ``TriggerMode`` cannot wait for a trigger and is reported as such.
"""

from __future__ import annotations

from typing import Any

from thintact_genicam.features import ApplyReport, apply_feature
from thintact_sdk.errors import DeviceError, UnsupportedFeatureError


def set_trigger(node_map: Any, source: str | None) -> None:
    """Make every frame wait for a trigger from ``source``; ``None`` returns to free running.

    Raises
    ------
    UnsupportedFeatureError
        When the device has no ``TriggerMode`` / ``TriggerSource`` or does not offer
        ``source`` (the message lists what it offers).
    """
    report = ApplyReport()
    if not node_map.has_node("TriggerMode"):
        raise UnsupportedFeatureError(
            "the device has no TriggerMode feature: it cannot wait for a trigger (pair its "
            "frames by time instead)"
        )
    if node_map.has_node("TriggerSelector"):
        choices = list(getattr(node_map.TriggerSelector, "symbolics", ()))
        if "FrameStart" in choices:
            apply_feature(node_map, "TriggerSelector", "FrameStart", report)
    if source is None:
        apply_feature(node_map, "TriggerMode", "Off", report)
        return
    if not apply_feature(node_map, "TriggerSource", source, report):
        raise UnsupportedFeatureError(
            f"the device has TriggerMode but cannot select TriggerSource {source!r} "
            f"({report.missing.get('TriggerSource', 'not writable')})"
        )
    if not apply_feature(node_map, "TriggerMode", "On", report):
        raise UnsupportedFeatureError(
            f"TriggerMode cannot be switched on ({report.missing['TriggerMode']})"
        )


def fire_software_trigger(node_map: Any) -> None:
    """Execute ``TriggerSoftware`` once.

    Raises
    ------
    UnsupportedFeatureError
        When the device has no ``TriggerSoftware`` command.
    DeviceError
        When the device refuses it.
    """
    if not node_map.has_node("TriggerSoftware"):
        raise UnsupportedFeatureError("the device has no TriggerSoftware command")
    try:
        node_map.TriggerSoftware.execute()
    except Exception as err:  # noqa: BLE001 - genapi raises many kinds
        raise DeviceError(f"the device refused TriggerSoftware: {err}") from None
