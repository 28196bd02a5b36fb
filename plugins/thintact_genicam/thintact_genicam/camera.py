"""``genicam``: any GenICam/GenTL camera through harvesters.

Settings (``camera.settings`` of the profile)
---------------------------------------------
cti
    The vendor's GenTL producer file (JAI's for the GO-5000C-USB); relative paths are
    relative to the profile file. Without it, the only producer on ``GENICAM_GENTL64_PATH``.
serial, device_id, index
    Which device of the producer (by serial number, GenTL id, or position; default index 0).
Width, Height, OffsetX, OffsetY, PixelFormat, ExposureTime, Gain, AcquisitionFrameRate
    Standard features (or the aliases of :mod:`thintact_genicam.features`).
features
    ``{Name: value}`` of vendor-specific features, written after the standard ones.
strict
    When true, a setting the device lacks raises ``UnsupportedFeatureError``; by default it
    is a :class:`GenICamSettingWarning` and is listed in ``capabilities().missing``.
num_buffers
    Buffers the producer may fill ahead of the host (default 8).
reconnect_s
    When > 0, a device lost mid-stream is reopened (same device, same settings) for up to
    this many seconds before ``DeviceLostError`` is raised (default 0: raise at once).

Frames
------
``RawFrame.data`` is the image as delivered (``H × W`` mosaic/mono, ``H × W × C`` for
RGB formats), ``frame_id`` the producer's frame id, ``device_timestamp_ns`` the device's
timestamp when the producer reports one. Gaps in frame ids are counted
(``dropped_frames``) and the first frame after a gap has ``meta["dropped_before"]``.
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from thintact_genicam.features import (
    STANDARD,
    ApplyReport,
    apply_feature,
    feature_range,
    normalise_settings,
    read_feature,
)
from thintact_genicam.producers import quiet_harvesters, resolve_producer
from thintact_genicam.shared import acquire_harvester, release_harvester
from thintact_genicam.trigger import fire_software_trigger, set_trigger
from thintact_sdk.errors import (
    CameraSettingsError,
    DeviceError,
    DeviceLostError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    UnsupportedFeatureError,
)
from thintact_sdk.frames import RawFrame
from thintact_sdk.interfaces import Camera, CameraCapabilities, Range
from thintact_sdk.plugin_support import (
    CameraSettings,
    FrameGapCounter,
    Profile,
    bit_depth_problem,
    parse_camera_settings,
)

MAX_WAIT_S = 3600.0


class GenICamPluginSettings(CameraSettings):
    """The plugin's own ``camera.settings`` keys and their types; the other keys are the
    standard feature names of :data:`thintact_genicam.features.STANDARD` (and aliases)."""

    cti: str | None = None
    serial: str | int | None = None
    device_id: str | None = None
    index: int = Field(default=0, ge=0, strict=True)
    features: dict[str, Any] = Field(default_factory=dict)
    strict: bool = Field(default=False, strict=True)
    num_buffers: int = Field(default=8, ge=1, le=1024, strict=True)
    reconnect_s: float = Field(default=0.0, ge=0, le=MAX_WAIT_S)


PLUGIN_KEYS = set(GenICamPluginSettings.model_fields)


class GenICamSettingWarning(UserWarning):
    """A profile camera setting the device cannot honour (it lacks or locks the feature)."""


class GenICamCamera(Camera):
    """A GenTL device as a :class:`~thintact_sdk.interfaces.Camera`."""

    name = "genicam"

    def __init__(self, profile: Profile, settings: dict[str, Any]) -> None:
        from thintact_genicam.features import ALIASES

        unknown = sorted(k for k in settings if k not in PLUGIN_KEYS and k not in STANDARD
                         and k not in ALIASES)
        if unknown:
            raise CameraSettingsError(
                f"invalid genicam camera settings:\n  - camera.settings.{unknown[0]}: unknown "
                f"genicam camera setting ({', '.join(unknown)}); known: "
                f"{', '.join(sorted(PLUGIN_KEYS | set(STANDARD)))} (vendor features go under "
                "'features')"
            )
        parse_camera_settings(GenICamPluginSettings, {k: v for k, v in settings.items() if k in PLUGIN_KEYS},
                              "genicam")
        cti = settings.get("cti")
        self.cti: Path = resolve_producer(profile.resolve_path(str(cti)) if cti else None)
        self.profile = profile
        self.features = normalise_settings(settings)
        self.vendor_features: dict[str, Any] = dict(settings.get("features") or {})
        self.strict = bool(settings.get("strict", False))
        self.num_buffers = int(settings.get("num_buffers", 8))
        self.reconnect_s = float(settings.get("reconnect_s", 0.0))
        if "serial" in settings:
            self._search: Any = {"serial_number": str(settings["serial"])}
        elif "device_id" in settings:
            self._search = {"id_": str(settings["device_id"])}
        else:
            self._search = int(settings.get("index", 0))
        self._harvester: Any = None
        self._ia: Any = None
        self._report = ApplyReport()
        self._gaps = FrameGapCounter()
        self._exposure_us: float | None = None
        self._gain_db: float | None = None
        self._reconnects = 0
        self._reconnected = False
        self._trigger_source: str | None = None
        self._is_open = False

    # -- lifecycle --------------------------------------------------------------------
    def open(self) -> None:
        """Load the producer, open the device, apply the settings and start streaming."""
        if self._ia is not None:
            self._release()  # opening again restarts cleanly
        quiet_harvesters()
        h = acquire_harvester(self.cti)  # shared: two cameras of one producer (two fingers)
        try:
            devices = list(h.device_info_list)
            if not devices:
                raise DeviceNotFoundError(
                    f"GenTL producer {self.cti.name} finds no camera: is it plugged in and "
                    "powered (and not opened by another program)?"
                )
            if isinstance(self._search, int) and not 0 <= self._search < len(devices):
                raise DeviceNotFoundError(
                    f"camera index {self._search} requested but {self.cti.name} offers "
                    f"{len(devices)} device(s)"
                )
            try:
                ia = h.create(self._search)
            except Exception as err:  # noqa: BLE001
                offered = ", ".join(
                    f"{getattr(d, 'serial_number', '?')} ({getattr(d, 'id_', '?')})" for d in devices
                )
                raise DeviceNotFoundError(
                    f"cannot open camera {self._search!r} on {self.cti.name}: {err}; "
                    f"offered (serial, id): {offered}"
                ) from None
        except BaseException:
            release_harvester(self.cti, h)
            raise
        self._harvester, self._ia = h, ia
        try:
            ia.num_buffers = max(self.num_buffers, int(ia.min_num_buffers))
            self._apply_all()
            if self._trigger_source is not None:  # a reconnect keeps the trigger
                set_trigger(ia.remote_device.node_map, self._trigger_source)
            ia.start()
        except BaseException:
            self._release()
            raise
        self._gaps = FrameGapCounter()
        self._is_open = True

    def _apply_all(self) -> None:
        nm = self._ia.remote_device.node_map
        report = ApplyReport()
        for feature, value in self.features.items():
            apply_feature(nm, feature, value, report)
        for feature, value in self.vendor_features.items():
            apply_feature(nm, feature, value, report)
        for feature, reason in report.missing.items():
            msg = f"camera setting {feature} cannot be honoured: {reason}"
            if self.strict:
                raise UnsupportedFeatureError(f"{msg} (settings.strict is on)")
            warnings.warn(msg, GenICamSettingWarning, stacklevel=3)
        self._report = report
        pixel_format = read_feature(nm, "PixelFormat")
        depth_problem = bit_depth_problem(str(pixel_format), self.profile) if pixel_format else None
        if depth_problem:
            warnings.warn(f"genicam: {depth_problem}", GenICamSettingWarning, stacklevel=3)
        exposure = read_feature(nm, "ExposureTime")
        gain = read_feature(nm, "Gain")
        self._exposure_us = float(exposure) if exposure is not None else None
        self._gain_db = float(gain) if gain is not None else None

    def _release(self) -> None:
        ia, h = self._ia, self._harvester
        self._ia = self._harvester = None
        for step in (
            lambda: ia.stop() if ia is not None else None,
            lambda: ia.destroy() if ia is not None else None,
            lambda: release_harvester(self.cti, h) if h is not None else None,
        ):
            try:
                step()
            except Exception:  # noqa: BLE001 - releasing a vanished device fails in many ways
                continue

    def close(self) -> None:
        """Stop streaming and release device and producer. Safe to call twice."""
        self._release()
        self._is_open = False

    # -- Camera API ---------------------------------------------------------------------
    @property
    def dropped_frames(self) -> int:
        """Frames lost since open, from gaps in the frame ids."""
        return self._gaps.dropped

    @property
    def reconnects(self) -> int:
        """How many times the device was reopened after being lost."""
        return self._reconnects

    def _node_map(self) -> Any:
        if self._ia is None:
            raise DeviceError("genicam camera is not open; call open() or use it in a with block")
        return self._ia.remote_device.node_map

    def capabilities(self) -> CameraCapabilities:
        nm = self._node_map()
        pf = nm.PixelFormat if nm.has_node("PixelFormat") else None
        fps_range = feature_range(nm, "AcquisitionFrameRate")
        exp_range = feature_range(nm, "ExposureTime")
        gain_range = feature_range(nm, "Gain")
        fps = read_feature(nm, "AcquisitionFrameRate")
        return CameraCapabilities(
            width=int(read_feature(nm, "Width") or 0),
            height=int(read_feature(nm, "Height") or 0),
            pixel_formats=list(pf.symbolics) if pf is not None else [],
            pixel_format=str(pf.value) if pf is not None else "",
            fps=float(fps) if fps is not None else None,
            fps_range=Range(*fps_range, "Hz") if fps_range else None,
            exposure_range_us=Range(*exp_range, "us") if exp_range else None,
            gain_range_db=Range(*gain_range, "dB") if gain_range else None,
            missing=sorted(self._report.missing),
        )

    def _set_while_streaming(self, feature: str, value: float) -> float:
        report = ApplyReport()
        if not apply_feature(self._node_map(), feature, value, report):
            raise UnsupportedFeatureError(
                f"genicam: {feature} not supported ({report.missing[feature]})"
            )
        return float(report.applied[feature])

    def set_exposure_us(self, exposure_us: float) -> None:
        """Set ``ExposureTime`` (us); frames read afterwards report the new value."""
        self._exposure_us = self._set_while_streaming("ExposureTime", exposure_us)
        self.features["ExposureTime"] = exposure_us

    def set_gain_db(self, gain_db: float) -> None:
        """Set ``Gain`` (dB)."""
        self._gain_db = self._set_while_streaming("Gain", gain_db)
        self.features["Gain"] = gain_db

    def set_trigger(self, source: str | None) -> None:
        """Wait for a trigger from ``source`` (``"Software"``, ``"Line0"``, ...) before each
        frame; ``None`` returns to free running. Acquisition is stopped while the trigger
        features are written (many devices lock them while streaming).

        Raises
        ------
        UnsupportedFeatureError
            When the device has no ``TriggerMode`` or does not offer ``source``.
        """
        nm = self._node_map()
        self._ia.stop()
        try:
            set_trigger(nm, source)
        finally:
            self._ia.start()
        self._trigger_source = source

    def fire_trigger(self) -> None:
        """Issue one software trigger (``TriggerSoftware``)."""
        fire_software_trigger(self._node_map())

    def read(self, timeout_s: float = 2.0) -> RawFrame:
        """The next frame; waits at most ``timeout_s``.

        Raises
        ------
        DeviceTimeoutError
            No frame within ``timeout_s`` while the device still answers.
        DeviceLostError
            The device or producer vanished (after ``reconnect_s`` of reconnect attempts).
        """
        from genicam.gentl import TimeoutException

        if self._ia is None:
            if self._is_open:
                return self._lost("the device was released after an earlier fault", timeout_s)
            raise DeviceError("genicam camera is not open; call open() or use it in a with block")
        deadline = time.monotonic() + timeout_s
        while True:
            wait = min(max(deadline - time.monotonic(), 1e-3), MAX_WAIT_S)
            try:
                buf = self._ia.fetch(timeout=wait)
            except TimeoutException:
                if not self._device_answers():
                    return self._lost("no frame and the device no longer answers", timeout_s)
                raise DeviceTimeoutError(
                    f"no frame from the GenICam camera within {timeout_s:.2f} s "
                    "(trigger mode on? frame rate too low?)"
                ) from None
            except Exception as err:  # noqa: BLE001 - any other GenTL fault means the device is gone
                return self._lost(f"{type(err).__name__}: {err}", timeout_s)
            try:
                with buf:
                    frame = self._to_raw(buf)
            except DeviceError:
                raise  # a frame this plugin cannot decode: the device itself is fine
            except Exception as err:  # noqa: BLE001
                return self._lost(f"{type(err).__name__}: {err}", timeout_s)
            if frame is not None:
                return frame
            if time.monotonic() >= deadline:
                raise DeviceTimeoutError(
                    f"only incomplete frames from the GenICam camera within {timeout_s:.2f} s"
                )

    def _device_answers(self) -> bool:
        try:
            return read_feature(self._ia.remote_device.node_map, "Width") is not None
        except Exception:  # noqa: BLE001
            return False

    def _to_raw(self, buf: Any) -> RawFrame | None:
        received = time.monotonic_ns()
        comps = buf.payload.components
        if not comps:
            return None  # an incomplete buffer: its frame id leaves a gap that is counted
        comp = comps[0]
        h, w = int(comp.height), int(comp.width)
        flat = np.asarray(comp.data)
        per_px = flat.size // (h * w) if h * w else 0
        if per_px < 1 or flat.size != per_px * h * w:
            raise DeviceError(
                f"frame {buf.frame_id}: {comp.data_format} payload of {flat.size} values does "
                f"not fit {w}×{h} (line padding or a pixel format harvesters cannot unpack); "
                "choose another PixelFormat"
            )
        data = flat.reshape(h, w) if per_px == 1 else flat.reshape(h, w, per_px)
        frame_id = int(buf.frame_id)
        try:
            device_ts: int | None = int(buf.timestamp_ns)
        except Exception:  # noqa: BLE001 - producers without device timestamps
            device_ts = None
        missing = self._gaps.update(frame_id)
        meta: dict[str, Any] = {"dropped_total": self._gaps.dropped}
        if missing:
            meta["dropped_before"] = missing
        if self._reconnected:
            meta["reconnected"] = True
            self._reconnected = False
        return RawFrame(
            data=data.copy(),
            timestamp_ns=received,
            frame_id=frame_id,
            pixel_format=str(comp.data_format),
            exposure_us=self._exposure_us,
            gain_db=self._gain_db,
            device_timestamp_ns=device_ts,
            meta=meta,
        )

    def _lost(self, why: str, timeout_s: float) -> RawFrame:
        self._release()
        if self.reconnect_s <= 0:
            self._is_open = False
            raise DeviceLostError(
                f"GenICam camera {self._search!r} on {self.cti.name} was lost mid-stream ({why}); "
                "check the cable and power, then open it again (or set camera.settings."
                "reconnect_s)"
            )
        deadline = time.monotonic() + self.reconnect_s
        last = why
        while time.monotonic() < deadline:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", GenICamSettingWarning)
                    self.open()
            except DeviceError as err:
                last = str(err)
                time.sleep(0.2)
                continue
            self._reconnects += 1
            self._reconnected = True
            return self.read(timeout_s)
        self._is_open = False
        raise DeviceLostError(
            f"GenICam camera {self._search!r} on {self.cti.name} was lost mid-stream ({why}) "
            f"and did not come back within {self.reconnect_s:.1f} s (last attempt: {last})"
        )
