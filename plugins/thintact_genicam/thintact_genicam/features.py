"""Profile camera settings → GenICam SFNC feature names, and applying them to a node map.

The profile may use the standard feature names (``Width``, ``Height``, ``OffsetX``,
``OffsetY``, ``PixelFormat``, ``ExposureTime`` [us], ``Gain`` [dB],
``AcquisitionFrameRate`` [Hz]) or the SDK's unit-bearing aliases (``width``, ``height``,
``offset_x``, ``offset_y``, ``pixel_format``, ``exposure_us``, ``gain_db``, ``fps``).
Vendor-specific features go under ``features: {Name: value}`` and are written as given.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from thintact_sdk.errors import DeviceError, UnsupportedFeatureError

ALIASES = {
    "width": "Width",
    "height": "Height",
    "offset_x": "OffsetX",
    "offset_y": "OffsetY",
    "pixel_format": "PixelFormat",
    "exposure_us": "ExposureTime",
    "gain_db": "Gain",
    "fps": "AcquisitionFrameRate",
}
STANDARD = ("PixelFormat", "Width", "Height", "OffsetX", "OffsetY",
            "AcquisitionFrameRate", "ExposureTime", "Gain")
"""The standard features, in the order they are applied (format and size before offsets)."""
FALLBACK_NAMES = {
    "ExposureTime": ("ExposureTime", "ExposureTimeAbs"),
    "AcquisitionFrameRate": ("AcquisitionFrameRate", "AcquisitionFrameRateAbs"),
}
UNITS = {"ExposureTime": "us", "Gain": "dB", "AcquisitionFrameRate": "Hz",
         "Width": "px", "Height": "px", "OffsetX": "px", "OffsetY": "px"}
# features that must be switched before the main one is writable
PREREQUISITES = {
    "ExposureTime": ("ExposureAuto", "Off"),
    "Gain": ("GainAuto", "Off"),
    "AcquisitionFrameRate": ("AcquisitionFrameRateEnable", True),
}
_WRITABLE = (2, 4)  # genapi EAccessMode WO, RW
_READABLE = (3, 4)  # RO, RW


@dataclass
class ApplyReport:
    """What applying the settings did: values set, and settings the device could not honour."""

    applied: dict[str, Any] = field(default_factory=dict)
    missing: dict[str, str] = field(default_factory=dict)
    """feature → reason (absent, not writable)."""


def normalise_settings(settings: dict[str, Any]) -> dict[str, Any]:
    """Standard feature name → value for every standard feature named in ``settings``.

    Raises
    ------
    DeviceError
        When a feature is given twice (``ExposureTime`` and ``exposure_us``).
    """
    out: dict[str, Any] = {}
    for key, value in settings.items():
        name = ALIASES.get(key, key)
        if name in STANDARD:
            if name in out:
                raise DeviceError(f"camera setting {name} given twice (as {name} and an alias)")
            out[name] = value
    return {name: out[name] for name in STANDARD if name in out}


def resolve_node_name(node_map: Any, name: str) -> str | None:
    """The name under which the device implements feature ``name``, or None."""
    for candidate in FALLBACK_NAMES.get(name, (name,)):
        if node_map.has_node(candidate):
            return candidate
    return None


def access_mode(node: Any) -> int:
    """genapi access mode of a harvesters node wrapper (0 NI, 1 NA, 2 WO, 3 RO, 4 RW)."""
    return int(node.node.get_access_mode())


def _check_value(feature: str, node: Any, value: Any) -> Any:
    if feature == "PixelFormat" or hasattr(node, "symbolics"):
        choices = list(node.symbolics)
        if str(value) not in choices:
            raise UnsupportedFeatureError(
                f"{feature} {value!r} is not offered by the device; it offers {', '.join(choices)}"
            )
        return str(value)
    if isinstance(value, bool):
        return value
    try:
        lo, hi = node.min, node.max
    except Exception:  # noqa: BLE001 - string/boolean/command nodes have no range
        return value
    unit = UNITS.get(feature, "")
    if not lo <= float(value) <= hi:
        raise DeviceError(
            f"{feature} {value} {unit} is outside the device's range {lo}..{hi} {unit}".rstrip()
        )
    if isinstance(lo, int) and isinstance(hi, int):
        inc = int(getattr(node, "inc", 1) or 1)
        ivalue = int(value)
        if ivalue != value or (ivalue - lo) % inc:
            raise DeviceError(f"{feature} must be an integer {lo} + k·{inc} {unit}, got {value}")
        return ivalue
    return float(value)


def apply_feature(node_map: Any, feature: str, value: Any, report: ApplyReport) -> bool:
    """Write one feature; records it in ``report``. Returns False if the device lacks it.

    Raises
    ------
    UnsupportedFeatureError
        When an enumeration value is not offered.
    DeviceError
        When the value is outside the device's range or the write fails.
    """
    name = resolve_node_name(node_map, feature)
    if name is None:
        report.missing[feature] = "the device has no such feature"
        return False
    prereq = PREREQUISITES.get(feature)
    if prereq is not None and node_map.has_node(prereq[0]):
        pnode = getattr(node_map, prereq[0])
        if access_mode(pnode) in _WRITABLE:
            try:
                pnode.value = prereq[1]
            except Exception:  # noqa: BLE001 - best effort; the main write reports failures
                pass
    node = getattr(node_map, name)
    if access_mode(node) not in _WRITABLE:
        current = read_feature(node_map, feature)
        if current is not None and _same(current, value):
            report.applied[feature] = current  # read-only, but already what was asked
            return True
        report.missing[feature] = (
            f"the device does not allow writing it now (it reads {current!r})"
        )
        return False
    checked = _check_value(feature, node, value)
    try:
        node.value = checked
    except Exception as err:  # noqa: BLE001 - genapi raises many kinds
        raise DeviceError(f"the device refused {feature} = {value}: {err}") from None
    report.applied[feature] = read_feature(node_map, feature)
    return True


def _same(current: Any, wanted: Any) -> bool:
    if isinstance(current, (int, float)) and isinstance(wanted, (int, float)):
        return abs(float(current) - float(wanted)) <= 1e-9 * max(1.0, abs(float(wanted)))
    return str(current) == str(wanted)


def read_feature(node_map: Any, feature: str) -> Any:
    """Current value of a feature, or None when absent or unreadable."""
    name = resolve_node_name(node_map, feature)
    if name is None:
        return None
    node = getattr(node_map, name)
    if access_mode(node) not in _READABLE:
        return None
    try:
        return node.value
    except Exception:  # noqa: BLE001
        return None


def feature_range(node_map: Any, feature: str) -> tuple[float, float] | None:
    """``(min, max)`` of a numeric feature, or None when the device lacks it."""
    name = resolve_node_name(node_map, feature)
    if name is None:
        return None
    node = getattr(node_map, name)
    try:
        return float(node.min), float(node.max)
    except Exception:  # noqa: BLE001
        return None
