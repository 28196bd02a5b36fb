"""Exception types of the ThinTact SDK.

Every error a user can act on derives from :class:`ThinTactError`; the CLI turns
these into a one-line message and exit status 2 instead of a traceback.
"""

from __future__ import annotations


class ThinTactError(Exception):
    """Base class of all SDK errors."""


class ProfileError(ThinTactError):
    """A device profile is missing, unreadable or fails validation."""


class CameraSettingsError(ProfileError):
    """A camera plugin's ``camera.settings`` holds an unknown key or a value of the wrong type."""


class PluginError(ThinTactError):
    """A plugin is unknown, failed to load or does not provide what was asked."""


class RecordingError(ThinTactError):
    """A recording directory is missing, truncated or malformed."""


class CalibrationError(ThinTactError):
    """A calibration bundle is missing, inconsistent or a solve failed."""


class DeviceError(ThinTactError):
    """A hardware device (camera, light controller, display) reported a fault."""


class DeviceNotFoundError(DeviceError):
    """The requested device is not present (unplugged, wrong index or path)."""


class DeviceLostError(DeviceError):
    """A device vanished while it was in use (unplugged mid-stream, port closed)."""


class DeviceTimeoutError(DeviceError):
    """A device did not answer within the allotted time."""


class ProtocolError(DeviceError):
    """A device answered with something that does not follow its protocol."""


class UnsupportedFeatureError(DeviceError):
    """The device lacks a feature the profile asks for (e.g. exposure on a virtual camera)."""


class EndOfStreamError(DeviceError):
    """A finite frame source (a replayed recording, a video file) has no more frames."""


class OutputError(ThinTactError):
    """An output path the user named cannot be used: empty, the wrong kind, or already
    holding data that would be overwritten without ``--force``."""


class InvalidShapeError(ThinTactError, ValueError):
    """An array the user supplied (a frame, measurement, scene, mask vector) has the wrong shape
    or number of channels; the message gives the expected and the actual shape. Also a
    :class:`ValueError`, for code that catches that."""


class InvalidValueError(ThinTactError, ValueError):
    """A parameter or setting the user supplied is outside its valid set or range (τ, a Bayer
    pattern, a backend name, an LED level); the message names it and what is allowed. Also a
    :class:`ValueError`, for code that catches that."""


class KernelSizeError(ThinTactError):
    """An imaging kernel whose tabulated families or separable terms would exceed the memory
    bound on this device (a large rotated mask or refraction); the message names the device,
    the size and the limit. Raised before anything of that size is allocated, so a caller
    may try smaller pieces of the sensor instead."""
