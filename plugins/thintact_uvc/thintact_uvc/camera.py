"""``uvc``: UVC/V4L2 cameras, lossless video files and image sequences through OpenCV.

Settings (``camera.settings`` of the profile)
---------------------------------------------
device
    Index, ``/dev/video*`` path, ``/dev/v4l/by-id/...`` name, video file or image-sequence
    pattern (see :mod:`thintact_uvc.sources`). Required.
width, height, fps, exposure_us, gain, fourcc
    Requested of live devices; what the device does not accept is listed in
    ``capabilities().missing`` with a :class:`UvcSettingWarning` (or an error with
    ``strict: true``). V4L2 takes the exposure in units of 100 us. For files, ``fps`` paces
    playback (default: as fast as read) and the others are missing.
convert_rgb
    Live devices only: false delivers the driver's frames unconverted, for UVC cameras that
    stream raw Bayer (``fourcc: BA81`` etc.; default true: OpenCV converts to colour).
pixel_format
    Name given to single-channel frames (default ``Mono8``/``Mono16`` by depth; say
    ``BayerRG16`` etc. when the frames are raw mosaics of another layout than the profile's).
loop
    Files only: start again at the end (default false).
crop, transpose, flip, rotate
    Reshape every frame before binning (lens sensors whose stream is not the gel's
    orientation or includes the housing): margins in pixels or fractions, rows ↔ columns,
    mirror, degrees counter-clockwise; applied in that order
    (:class:`thintact_sdk.device.camera_settings.FrameGeometrySettings`, docs/lens-sensors.md).
    ``capabilities()`` reports the reshaped size.
led_intensity
    Live DIGIT sensors: LED brightness 1..255, sent as the UVC zoom control
    (``CAP_PROP_ZOOM``) as digit-interface's ``set_intensity`` does; devices without that
    control list it in ``missing``. Files: missing.
open_timeout_s
    Limit on opening the source (default 10 s).

Frames
------
Colour frames are delivered as ``H × W × 3`` RGB (binning passes them through), gray frames
as ``H × W`` (binned as a Bayer mosaic with the profile's layout). Gray video files and image
sequences are read unconverted (``CAP_PROP_CONVERT_RGB`` off) so 16-bit data stay exact. Every read runs on a worker thread
and waits at most ``timeout_s``; a frame that arrives late is kept for the next read.
After the last frame of a file (without ``loop``), ``read`` raises :class:`EndOfVideo`.
"""

from __future__ import annotations

import concurrent.futures as cf
import os
import time
import warnings
from typing import Any

import cv2
import numpy as np
from pydantic import Field

from thintact_sdk.errors import (
    DeviceError,
    DeviceLostError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    EndOfStreamError,
    ProfileError,
    RecordingError,
    UnsupportedFeatureError,
)
from thintact_sdk.frames import RawFrame
from thintact_sdk.interfaces import Camera, CameraCapabilities, Range
from thintact_sdk.plugin_support import (
    FrameGeometrySettings,
    Profile,
    apply_geometry,
    crop_box,
    parse_camera_settings,
)
from thintact_uvc.sources import Source, resolve_source

V4L2_EXPOSURE_UNIT_US = 100.0


def _gray_codec(cap: Any) -> bool:
    """True when FFmpeg decodes to a gray pixel format (Y800, gray16 ``Y1\\0\\x10``, ...).

    Only those are read unconverted: FFmpeg's unconverted colour output is its packed codec
    format, which OpenCV cannot shape.
    """
    code = int(cap.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT) or 0)
    tag = bytes((code >> (8 * i)) & 0xFF for i in range(4))
    return tag in (b"Y800", b"GREY", b"Y8  ") or tag.startswith(b"Y1")


class EndOfVideo(EndOfStreamError):
    """A video file or image sequence has no more frames (and ``loop`` is off)."""


class UvcSettingWarning(UserWarning):
    """A setting the device or file cannot honour."""


class UvcCameraSettings(FrameGeometrySettings):
    """``camera.settings`` of the uvc camera: keys and types (see the module docstring)."""

    device: int | str | None = None
    width: int | None = Field(default=None, gt=0, strict=True)
    height: int | None = Field(default=None, gt=0, strict=True)
    fps: float | None = Field(default=None, ge=0, le=10_000)
    exposure_us: float | None = Field(default=None, gt=0)
    gain: float | None = None
    fourcc: str | None = None
    strict: bool = Field(default=False, strict=True)
    pixel_format: str | None = None
    loop: bool = Field(default=False, strict=True)
    open_timeout_s: float = Field(default=10.0, gt=0, le=3600)
    convert_rgb: bool = Field(default=True, strict=True)
    led_intensity: int | None = Field(default=None, ge=1, le=255, strict=True)


class UvcCamera(Camera):
    """An OpenCV ``VideoCapture`` source as a :class:`~thintact_sdk.interfaces.Camera`."""

    name = "uvc"

    def __init__(self, profile: Profile, settings: dict[str, Any]) -> None:
        self.geometry = parse_camera_settings(UvcCameraSettings, settings, "uvc")
        if "device" not in settings:
            raise ProfileError(
                "uvc camera needs camera.settings.device (index, /dev/video* path, "
                "/dev/v4l/by-id name, video file or img_%04d.png pattern)"
            )
        base = profile.source.parent if profile.source is not None else None
        self.source: Source = resolve_source(settings["device"], base)
        self.profile = profile
        self.settings = dict(settings)
        self.strict = bool(settings.get("strict", False))
        self.loop = bool(settings.get("loop", False))
        self.open_timeout_s = float(settings.get("open_timeout_s", 10.0))
        self._cap: Any = None
        self._pool: cf.ThreadPoolExecutor | None = None
        self._pending: cf.Future[tuple[bool, Any]] | None = None
        self._missing: list[str] = []
        self._frame_count = 0
        self._delivered = 0
        self._index = 0
        self._exposure_us: float | None = None
        self._next_due = 0.0
        self._last_format = str(settings.get("pixel_format", ""))
        self._is_open = False

    # -- lifecycle --------------------------------------------------------------------
    def open(self) -> None:
        """Open the source (bounded by ``open_timeout_s``) and apply the settings."""
        if self._cap is not None:
            self.close()  # opening again restarts cleanly
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
        self._pool = cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="uvc-read")
        fut = self._pool.submit(self._open_capture)
        try:
            cap = fut.result(timeout=self.open_timeout_s)
        except cf.TimeoutError:
            self._shutdown_pool()
            raise DeviceTimeoutError(
                f"opening {self.source.label} took longer than {self.open_timeout_s:.1f} s"
            ) from None
        if cap is None or not cap.isOpened():
            self._shutdown_pool()
            what = "camera" if self.source.is_live else "file"
            raise DeviceNotFoundError(
                f"OpenCV cannot open the {what} {self.source.label} (busy, no permission, or "
                "a format this OpenCV build cannot read)"
            )
        self._cap = cap
        self._missing = []
        self._apply_settings()
        self._frame_count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0) if not self.source.is_live else 0
        self._delivered = 0
        self._index = 0
        self._next_due = time.monotonic()
        self._is_open = True

    def _open_capture(self) -> Any:
        target = str(self.source.target)
        try:
            target.encode("utf-8")
        except UnicodeEncodeError:  # OpenCV's reader crashes (segmentation fault) on such a name
            raise ProfileError(f"camera.settings.device {target.encode('utf-8', 'surrogateescape')!r}: "
                               "the name is not valid UTF-8, which OpenCV cannot open; rename the "
                               "file") from None
        if self.source.kind == "device":
            cap = cv2.VideoCapture(self.source.target, cv2.CAP_V4L2)
        elif self.source.kind == "sequence":
            cap = cv2.VideoCapture(str(self.source.target), cv2.CAP_IMAGES)
        else:
            cap = cv2.VideoCapture(str(self.source.target), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            return cap
        if self.source.is_live:
            if not self.settings.get("convert_rgb", True):
                cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)  # raw Bayer UVC formats (BA81, GRBG...)
        elif self.source.kind == "sequence" or _gray_codec(cap):
            cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)  # keep 16-bit gray data exact
        return cap

    def _want(self, key: str, prop: int, value: float, scale: float = 1.0) -> None:
        ok = bool(self._cap.set(prop, value / scale))
        if ok:
            got = float(self._cap.get(prop)) * scale
            ok = abs(got - value) <= max(1e-6, 0.01 * abs(value))
        if not ok:
            self._missing.append(key)

    def _apply_settings(self) -> None:
        s = self.settings
        live = self.source.is_live
        if live and "fourcc" in s:
            code = str(s["fourcc"])
            if len(code) != 4:
                raise ProfileError(f"camera.settings.fourcc must be 4 characters, got {code!r}")
            self._want("fourcc", cv2.CAP_PROP_FOURCC, float(cv2.VideoWriter.fourcc(*code)))
        for key, prop in (("width", cv2.CAP_PROP_FRAME_WIDTH), ("height", cv2.CAP_PROP_FRAME_HEIGHT)):
            if key in s:
                if live:
                    self._want(key, prop, float(s[key]))
                elif int(self._cap.get(prop)) != int(s[key]):
                    self._missing.append(key)
        if "fps" in s and live:
            self._want("fps", cv2.CAP_PROP_FPS, float(s["fps"]))
        if "exposure_us" in s:
            if live:
                self._cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)  # V4L2: 1 = manual exposure
                self._want("exposure_us", cv2.CAP_PROP_EXPOSURE, float(s["exposure_us"]),
                           V4L2_EXPOSURE_UNIT_US)
            else:
                self._missing.append("exposure_us")
        if "gain" in s:
            if live:
                self._want("gain", cv2.CAP_PROP_GAIN, float(s["gain"]))
            else:
                self._missing.append("gain")
        if "led_intensity" in s:
            # DIGIT firmware: LED intensity is the UVC zoom control (digit-interface set_intensity)
            if not (live and self._cap.set(cv2.CAP_PROP_ZOOM, float(s["led_intensity"]))):
                self._missing.append("led_intensity")
        if live and "exposure_us" not in self._missing:
            exp = float(self._cap.get(cv2.CAP_PROP_EXPOSURE))
            self._exposure_us = exp * V4L2_EXPOSURE_UNIT_US if exp > 0 else None
        for key in self._missing:
            msg = f"uvc: {self.source.label} does not accept setting {key}={s.get(key)!r}"
            if self.strict:
                self.close()
                raise UnsupportedFeatureError(f"{msg} (settings.strict is on)")
            warnings.warn(msg, UvcSettingWarning, stacklevel=3)

    def _shutdown_pool(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
        self._pending = None

    def close(self) -> None:
        """Release the capture. Safe to call twice (a read stuck in the driver is abandoned)."""
        cap, self._cap = self._cap, None
        pending = self._pending
        self._shutdown_pool()
        if cap is not None and (pending is None or pending.done()):
            cap.release()
        self._is_open = False

    # -- Camera API ---------------------------------------------------------------------
    def capabilities(self) -> CameraCapabilities:
        """Size and rate as OpenCV reports them; the pixel format of the last frame read."""
        cap = self._capture()
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        if not self.source.is_live and "fps" in self.settings:
            fps = float(self.settings["fps"])
        live_exposure = self.source.is_live and "exposure_us" not in self._missing
        height, width = self._reshaped_size(int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
                                            int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)))
        return CameraCapabilities(
            width=width,
            height=height,
            pixel_formats=[self._last_format] if self._last_format else [],
            pixel_format=self._last_format,
            fps=fps if fps > 0 else None,
            exposure_range_us=Range(0.0, float("inf"), "us") if live_exposure else None,
            missing=list(self._missing),
        )

    def _reshaped_size(self, height: int, width: int) -> tuple[int, int]:
        """``(rows, cols)`` of a delivered ``height × width`` frame after the geometry settings."""
        g = self.geometry
        if g.crop is not None and height > 0 and width > 0:
            t, b, left, right = crop_box(height, width, g.crop)
            height, width = height - t - b, width - left - right
        if g.transpose != (g.rotate in (90, 270)):
            height, width = width, height
        return height, width

    def _capture(self) -> Any:
        if self._cap is None:
            raise DeviceError("uvc camera is not open; call open() or use it in a with block")
        return self._cap

    def set_exposure_us(self, exposure_us: float) -> None:
        """Set a live device's exposure (us; V4L2 units of 100 us)."""
        cap = self._capture()
        if not self.source.is_live or not cap.set(cv2.CAP_PROP_EXPOSURE, exposure_us / V4L2_EXPOSURE_UNIT_US):
            raise UnsupportedFeatureError(f"uvc: {self.source.label} does not accept an exposure time")
        self._exposure_us = float(exposure_us)

    def set_gain_db(self, gain_db: float) -> None:
        """Set a live device's gain (device units; UVC does not define dB)."""
        cap = self._capture()
        if not self.source.is_live or not cap.set(cv2.CAP_PROP_GAIN, gain_db):
            raise UnsupportedFeatureError(f"uvc: {self.source.label} does not accept a gain")

    def read(self, timeout_s: float = 2.0) -> RawFrame:
        """The next frame, waiting at most ``timeout_s``.

        Raises
        ------
        DeviceTimeoutError
            No frame in time (the late frame is kept for the next call).
        DeviceLostError
            A live device stopped delivering and its node is gone (unplugged).
        EndOfVideo
            After the last frame of a file without ``loop``.
        RecordingError
            A file ends before the frame count its header announces (truncated / corrupt).
        """
        cap = self._capture()
        assert self._pool is not None
        start = time.monotonic()
        pace = float(self.settings.get("fps", 0) or 0) if not self.source.is_live else 0.0
        if pace > 0:
            wait = self._next_due - start
            if wait > timeout_s:
                time.sleep(max(timeout_s, 0.0))
                raise DeviceTimeoutError(f"uvc: next file frame is due in {wait:.2f} s")
            if wait > 0:
                time.sleep(wait)
            self._next_due = max(self._next_due, start) + 1.0 / pace
        if self._pending is None:
            self._pending = self._pool.submit(cap.read)
        remaining = max(timeout_s - (time.monotonic() - start), 0.0)
        try:
            ok, img = self._pending.result(timeout=remaining)
        except cf.TimeoutError:
            raise DeviceTimeoutError(
                f"uvc: no frame from {self.source.label} within {timeout_s:.2f} s"
            ) from None
        except (cv2.error, OSError) as err:  # the driver or backend failed inside read()
            raise DeviceLostError(f"uvc camera {self.source.label} failed while reading: {err}") from None
        finally:
            if self._pending is not None and self._pending.done():
                self._pending = None
        if not ok or img is None:
            return self._no_frame(timeout_s)
        received = time.monotonic_ns()
        pos_ms = float(cap.get(cv2.CAP_PROP_POS_MSEC) or 0.0)
        frame_id = self._delivered
        self._delivered += 1
        self._index += 1
        data, fmt = self._to_rgb(img)
        data = apply_geometry(data, self.geometry)
        self._last_format = fmt
        return RawFrame(
            data=data,
            timestamp_ns=received,
            frame_id=frame_id,
            pixel_format=fmt,
            exposure_us=self._exposure_us,
            device_timestamp_ns=int(pos_ms * 1e6) if pos_ms > 0 else None,
            meta={"source": self.source.label, "index": self._index - 1},
        )

    def _to_rgb(self, img: np.ndarray) -> tuple[np.ndarray, str]:
        depth = {np.dtype(np.uint8): "8", np.dtype(np.uint16): "16"}.get(img.dtype, "32f")
        if img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 1):
            gray = img.reshape(img.shape[0], img.shape[1])
            return np.ascontiguousarray(gray), str(self.settings.get("pixel_format", f"Mono{depth}"))
        if img.ndim == 3 and img.shape[2] in (3, 4):
            return np.ascontiguousarray(img[..., 2::-1]), f"RGB{depth}"
        raise DeviceError(f"uvc: unexpected frame shape {img.shape} from {self.source.label}")

    def _no_frame(self, timeout_s: float) -> RawFrame:
        if self.source.is_live:
            node = self.source.target if isinstance(self.source.target, str) else (
                f"/dev/video{self.source.target}")
            if not os.path.exists(node):
                self.close()
                raise DeviceLostError(f"uvc camera {self.source.label} was unplugged ({node} is gone)")
            raise DeviceError(f"uvc camera {self.source.label} returned no frame (driver error)")
        if self._frame_count and self._index < self._frame_count:
            raise RecordingError(
                f"{self.source.label} is truncated or corrupt: frame {self._index} of "
                f"{self._frame_count} cannot be read"
            )
        if not self.loop:
            raise EndOfVideo(
                f"{self.source.label} ended after {self._index} frames (set "
                "camera.settings.loop: true to play it again)"
            )
        if self._index == 0:
            raise RecordingError(f"{self.source.label} holds no readable frame")
        cap = self._capture()
        if self.source.kind == "sequence":
            cap.release()
            self._cap = self._open_capture()
        else:
            cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
        self._index = 0
        return self.read(timeout_s)
