"""The virtual camera: simulated ThinTact frames as a Bayer ``RGGB`` mosaic (a plain frame for
a monochrome profile; distinct Gr and Gb sites for a profile with per-site planes).

Settings (``profile.camera.settings`` merged with the factory's ``settings``):

``scenes``          library name of :data:`thintact_sdk.simulation.scenes.LIBRARY`, ``"tactile"``
                    (the tactile simulator's membrane: unloaded, then 8 ball presses, see
                    :mod:`thintact_virtual.tactile_scenes`) or a list of names (default
                    ``"gelsight"``); frame k shows ``names[k % len]`` with index ``k // len``
                    (GelSight press / random seed / tactile press).
``slot``            scene-slot key (default the profile's name); a scene set there overrides
                    the library.
``fps``             frame rate the reads are paced to; 0 = as fast as possible.
``seed``            noise seed (default 0).
``noise``           add Poisson + read noise (default true); else the expected DN, rounded.
``white_level_dn``  DN above black of the brightest all-white pixel at 10 000 us
                    (default 0.6·(saturation - black)).
``exposure_us``     exposure (default 10 000 us); the signal scales linearly with it.

A profile declaring ``sensor.tone_curve`` gets frames encoded with that curve (as a camera's
ISP would); :func:`thintact_sdk.device.cameras.to_measurement` undoes it.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from typing import Any

import numpy as np
from pydantic import Field

from thintact_sdk.algorithms import (
    SCENE_LIBRARY,
    Simulator,
    make_scene,
    scene_for_channels,
    signal_to_dn,
)
from thintact_sdk.errors import DeviceError, ThinTactError, UnsupportedFeatureError
from thintact_sdk.frames import RawFrame
from thintact_sdk.interfaces import Camera, CameraCapabilities, Range
from thintact_sdk.plugin_support import (
    REFERENCE_EXPOSURE_US,
    CameraSettings,
    Profile,
    get_scene_slot,
    mosaic_from_planes,
    mosaic_from_rgb,
    parse_camera_settings,
    white_level_dn,
)
from thintact_sdk.plugin_support import encode as encode_tone
from thintact_virtual.tactile_scenes import CYCLE, TACTILE_SCENE, tactile_scene

EXPOSURE_RANGE_US = Range(10.0, 1_000_000.0, "us")


MIN_FPS = 1e-3
"""Slowest frame rate the virtual camera paces itself to (frames/s); 0 is unpaced."""
RAW_MAX_DN = 65535
"""Largest DN a raw frame (uint16) holds."""


class VirtualCameraSettings(CameraSettings):
    """``camera.settings`` of the virtual camera (see the module docstring)."""

    scenes: str | list[str] = "gelsight"
    slot: str | None = None
    fps: float = Field(default=0.0, ge=0, le=10_000)
    seed: int = Field(default=0, ge=0, strict=True)
    noise: bool = Field(default=True, strict=True)
    white_level_dn: float | None = Field(default=None, gt=0)
    exposure_us: float = Field(default=REFERENCE_EXPOSURE_US, gt=0)


class VirtualCamera(Camera):
    """A camera whose frames are the simulator's images of a scene (see module docstring)."""

    name = "virtual"

    def __init__(self, profile: Profile, settings: dict[str, Any] | None = None) -> None:
        base = dict(profile.camera.settings) if profile.camera is not None else {}
        base.update(settings or {})
        self.profile = profile
        self.settings = base
        parsed = parse_camera_settings(VirtualCameraSettings, base, "virtual")
        names = parsed.scenes
        self.scene_names: list[str] = [names] if isinstance(names, str) else list(names)
        for n in self.scene_names:
            if n not in SCENE_LIBRARY and n != TACTILE_SCENE:
                raise ThinTactError(
                    f"virtual camera: unknown scene {n!r}; library scenes: "
                    f"{', '.join([*SCENE_LIBRARY, TACTILE_SCENE])}"
                )
        if not self.scene_names:
            raise ThinTactError("virtual camera: 'scenes' is an empty list")
        if 0 < parsed.fps < MIN_FPS:  # one frame a second... or 1e-300: int(1e9 / fps) overflowed
            raise ThinTactError(f"virtual camera: fps {parsed.fps:g}: 0 (as fast as frames are read) "
                                f"or at least {MIN_FPS:g} frames/s")
        if profile.noise.saturation_dn > RAW_MAX_DN:
            raise ThinTactError(
                f"virtual camera: noise.saturation_dn {profile.noise.saturation_dn:g} is beyond the "
                f"{RAW_MAX_DN} DN its 16-bit raw frames hold (the frames wrapped around)")
        self.fps = parsed.fps
        self.noise = parsed.noise
        self.seed = parsed.seed
        self.slot_key = parsed.slot if parsed.slot is not None else profile.name
        self._exposure_us = parsed.exposure_us
        self._check_exposure(self._exposure_us)
        self._white_dn = white_level_dn(profile, base)
        self._sim: Simulator | None = None
        self._gain = 0.0
        self._rng = np.random.default_rng(self.seed)
        self._frame_id = 0
        self._library_index = 0
        self._next_due_ns = 0
        self._linear_cache: OrderedDict[Any, np.ndarray] = OrderedDict()
        self._scenes: dict[Any, np.ndarray] = {}
        self._is_open = False
        self._level: float | None = None
        nz = profile.noise
        bits = 12 if nz.saturation_dn <= 4095 else 16
        mono = len(profile.sensor.channels) == 1
        self.pixel_format = f"Mono{bits}" if mono else f"BayerRG{bits}"
        self._site = 1 if mono else 2  # raw pixels per measurement pixel along each axis

    @staticmethod
    def _check_exposure(exposure_us: float) -> None:
        if not EXPOSURE_RANGE_US.min <= exposure_us <= EXPOSURE_RANGE_US.max:
            raise ThinTactError(
                f"virtual camera: exposure {exposure_us} us outside "
                f"{EXPOSURE_RANGE_US.min}..{EXPOSURE_RANGE_US.max} us"
            )

    # -- Camera API -----------------------------------------------------------------------
    def open(self) -> None:
        if self._is_open:
            return
        self._sim = Simulator(self.profile)
        self._gain = self._sim.reference_gain(self._white_dn)
        self._level = self._sim.physics.get("saturation", {}).get("level_dn")
        self._next_due_ns = time.monotonic_ns()
        self._is_open = True

    def close(self) -> None:
        """Close the camera and release what rendering held: the simulator and its cached
        signals (up to 256 MB; a wizard's calibration runs after the capture with the camera
        closed). Opening again builds them anew."""
        self._is_open = False
        self._sim = None
        self._linear_cache.clear()
        self._scenes.clear()

    def capabilities(self) -> CameraCapabilities:
        return CameraCapabilities(
            width=self._site * self.profile.sensor.cols,
            height=self._site * self.profile.sensor.rows,
            pixel_formats=[self.pixel_format],
            pixel_format=self.pixel_format,
            fps=self.fps or None,
            fps_range=Range(0.0, 1000.0, "Hz"),
            exposure_range_us=EXPOSURE_RANGE_US,
            gain_range_db=None,
            missing=[],
        )

    def set_exposure_us(self, exposure_us: float) -> None:
        """Set the exposure (us); the signal scales linearly with it."""
        self._check_exposure(float(exposure_us))
        self._exposure_us = float(exposure_us)

    def set_gain_db(self, gain_db: float) -> None:
        raise UnsupportedFeatureError("virtual camera: gain control not supported")

    @property
    def exposure_us(self) -> float:
        return self._exposure_us

    @property
    def gain_dn_per_unit(self) -> float:
        """DN per simulator unit at the current exposure."""
        return self._gain * self._exposure_us / REFERENCE_EXPOSURE_US

    def read(self, timeout_s: float = 2.0) -> RawFrame:
        """Render the next frame (paced to ``fps``)."""
        if not self._is_open or self._sim is None:
            raise DeviceError("virtual camera: read() before open()")
        if self.fps > 0:
            now = time.monotonic_ns()
            wait_s = (self._next_due_ns - now) / 1e9
            if wait_s > timeout_s:
                from thintact_sdk.errors import DeviceTimeoutError

                raise DeviceTimeoutError("virtual camera: next frame not due within the timeout")
            if wait_s > 0:
                time.sleep(wait_s)
            self._next_due_ns = max(self._next_due_ns, now) + int(1e9 / self.fps)
        scene, key = self._current_scene()
        signal = self._sim.signal_dn_from_linear(self._linear(scene, key)[None],
                                                 self.gain_dn_per_unit)[0]
        rng = self._rng if self.noise else None
        dn = signal_to_dn(signal, self.profile.noise, rng, saturation_dn=self._level)
        if self.profile.sensor.tone_curve is not None:  # the camera's ISP encodes it
            dn = np.clip(encode_tone(dn, self.profile), 0, self.profile.noise.saturation_dn)
        dn16 = np.clip(np.round(dn), 0, RAW_MAX_DN).astype(np.uint16)
        frame = RawFrame(
            data=self._mosaic(dn16),
            timestamp_ns=time.monotonic_ns(),
            frame_id=self._frame_id,
            pixel_format=self.pixel_format,
            exposure_us=self._exposure_us,
            gain_db=None,
            meta={"scene": scene, "scene_source": "slot" if key[0] == "slot" else
                  f"{key[0]}:{key[1]}"},
        )
        self._frame_id += 1
        return frame

    WARM_UP_SCENES = 64
    """Most scenes :meth:`warm_up` renders ahead."""

    def warm_up(self) -> float:
        """Render ahead every scene the next frames show (the tactile cycle, the library's
        named scenes; not ``random``, whose scenes never repeat), at most
        :data:`WARM_UP_SCENES`, so that frames come at the camera's pace from the first one
        on (``open_group`` calls it before pairing). Returns the seconds spent."""
        if not self._is_open or self._sim is None:
            raise DeviceError("virtual camera: warm_up() before open()")
        t0 = time.perf_counter()
        period = {TACTILE_SCENE: CYCLE, "random": 0}
        names = self.scene_names
        if "gelsight" in names:
            from thintact_sdk.algorithms import gelsight_count

            period["gelsight"] = gelsight_count()
        frames = len(names) * max(period.get(n, 1) for n in names)
        start = self._library_index
        try:
            for _ in range(min(frames, self.WARM_UP_SCENES)):
                if names[self._library_index % len(names)] == "random":
                    self._library_index += 1
                    continue
                scene, key = self._current_scene()
                self._linear(scene, key)
        finally:
            self._library_index = start
        return time.perf_counter() - t0

    # -- rendering ------------------------------------------------------------------------
    def _mosaic(self, dn: np.ndarray) -> np.ndarray:
        """The sensor's raw frame: an RGGB mosaic, or the plain frame of a monochrome sensor."""
        if dn.shape[2] == 1:
            return dn[..., 0]
        return mosaic_from_planes(dn, "RGGB") if dn.shape[2] == 4 else mosaic_from_rgb(dn, "RGGB")

    def _current_scene(self) -> tuple[np.ndarray, tuple[Any, ...]]:
        version, slot_scene = get_scene_slot(self.slot_key).snapshot()
        if slot_scene is not None:
            return slot_scene, ("slot", self.slot_key, version)
        k = self._library_index
        self._library_index += 1
        name = self.scene_names[k % len(self.scene_names)]
        index = k // len(self.scene_names)
        if name == "gelsight":
            from thintact_sdk.algorithms import gelsight_count

            index %= gelsight_count()
        elif name == TACTILE_SCENE:
            index %= CYCLE
        elif name != "random":
            index = 0
        key = (name, index)
        if key not in self._scenes and name == TACTILE_SCENE:
            self._scenes[key] = tactile_scene(self.profile, index)
        elif key not in self._scenes:
            self._scenes[key] = make_scene(name, self.profile.scene.rows,
                                           self.profile.scene.cols, index)
        return self._scenes[key], key

    def _linear(self, scene: np.ndarray, key: tuple[Any, ...]) -> np.ndarray:
        """Linear signal (simulator units, ``R × S × 3``), cached per scene."""
        if key in self._linear_cache:
            self._linear_cache.move_to_end(key)
            return self._linear_cache[key]
        assert self._sim is not None
        x = np.asarray(scene, dtype=float)
        if x.shape != (self.profile.scene.rows, self.profile.scene.cols, 3):
            raise ThinTactError(
                f"virtual camera: scene shape {x.shape} does not match the profile's "
                f"{self.profile.scene.rows}×{self.profile.scene.cols}×3"
            )
        x = scene_for_channels(x, len(self.profile.sensor.channels))  # mono, R/Gr/Gb/B
        lin = self._sim.linear_batch(x[None])[0]
        self._linear_cache[key] = lin
        limit = max(2, int(256e6 // max(lin.nbytes, 1)))
        while len(self._linear_cache) > limit:
            old, _ = self._linear_cache.popitem(last=False)
            self._scenes.pop(old, None)
        return lin
