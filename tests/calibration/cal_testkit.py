"""Test doubles for the calibration tests: a synthetic T2S device with a display and camera."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from thintact_sdk.calibration import synthetic
from thintact_sdk.calibration.solver import ChannelMatrices
from thintact_sdk.errors import DeviceTimeoutError
from thintact_sdk.formats.profiles import Profile, load_profile
from thintact_sdk.formats.recording import RecordingWriter
from thintact_sdk.frames import RawFrame
from thintact_sdk.interfaces import Camera, CameraCapabilities, Display, Range
from thintact_sdk.pixels.bayer import mosaic_from_rgb
from thintact_sdk.reconstruction.t2s import SystemMatrices

REFERENCE_EXPOSURE_US = 10000.0


def synthetic_profile(name: str = "cal-synthetic", **display: Any) -> Profile:
    """virtual-mini's optics shrunk to the synthetic system's 64×80 sensor / 24×32 scene."""
    d = load_profile("virtual-mini").contract_dict()
    d["name"] = name
    d["sensor"] = {"rows": 64, "cols": 80, "pixel_pitch_um": 10.0, "channels": ["R", "G", "B"]}
    d["scene"] = {"rows": 24, "cols": 32, "pixel_pitch_um": 31.5}
    d["display"] = {"plugin": "virtual", "pixel_pitch_um": 31.5, "settle_s": 0.0, **display}
    d["camera"] = {"plugin": "virtual", "settings": {}}
    d["calibration_limits"] = {"min_psnr_db": 18.0, "min_ssim": 0.5}
    return Profile.model_validate(d)


def synthetic_matrices(gains_dn: tuple[float, float, float] = (8.0, 10.0, 7.0), seed: int = 3) -> SystemMatrices:
    """Three channels of :func:`synthetic.system` with different gains (white peaks at about
    70 % of full scale at 10 ms with the defaults)."""
    chans = [synthetic.system(seed=seed, gain_dn=g) for g in gains_dn]
    return SystemMatrices(
        np.stack([c.Po for c in chans]), np.stack([c.Qo for c in chans]),
        np.stack([c.Pc for c in chans]), np.stack([c.Qc for c in chans]),
    )


def channel(sm: SystemMatrices, c: int) -> ChannelMatrices:
    po, qo, pc, qc = (np.asarray(a, np.float64) for a in sm.channel(c))
    return ChannelMatrices(po, qo, pc, qc)


def measure(sm: SystemMatrices, profile: Profile, scene: np.ndarray, rng: np.random.Generator | None,
            exposure_us: float = REFERENCE_EXPOSURE_US, offset_dn: float = 0.0) -> np.ndarray:
    """Raw DN ``R × S × 3`` (black included) of ``scene``; Poisson + read noise when ``rng``."""
    nz = profile.noise
    signal = sm.forward(scene.astype(np.float64)) * (exposure_us / REFERENCE_EXPOSURE_US) + offset_dn
    if rng is not None:
        e = rng.poisson(np.clip(signal, 0, None) * nz.electrons_per_dn) / nz.electrons_per_dn
        signal = e + rng.normal(0.0, nz.read_noise_dn, signal.shape)
    return np.clip(np.rint(signal + nz.black_level_dn), 0, nz.saturation_dn)


class FakeDisplay(Display):
    """Remembers the scene shown."""

    def __init__(self) -> None:
        self.current: np.ndarray | None = None
        self.shown = 0
        self.opened = False

    def open(self) -> None:
        self.opened = True

    def close(self) -> None:
        self.opened = False

    def show(self, scene: np.ndarray) -> None:
        self.current = np.array(scene, np.float32)
        self.shown += 1


class FakeCamera(Camera):
    """Renders the fake display's scene through ``sm`` as a Bayer mosaic (uint16)."""

    name = "fake"

    def __init__(self, profile: Profile, sm: SystemMatrices, display: FakeDisplay, noise: bool = True,
                 seed: int = 0, exposure_us: float = REFERENCE_EXPOSURE_US, fail_after: int | None = None) -> None:
        self.profile, self.sm, self.display = profile, sm, display
        self.rng = np.random.default_rng(seed) if noise else None
        self.exposure_us = exposure_us
        self.frame_id = 0
        self.fail_after = fail_after

    def open(self) -> None:
        self._is_open = True

    def close(self) -> None:
        self._is_open = False

    def capabilities(self) -> CameraCapabilities:
        return CameraCapabilities(160, 128, ["BayerRG12"], "BayerRG12",
                                  exposure_range_us=Range(10.0, 1e6, "us"))

    def set_exposure_us(self, exposure_us: float) -> None:
        self.exposure_us = float(exposure_us)

    def read(self, timeout_s: float = 2.0) -> RawFrame:
        if self.fail_after is not None and self.frame_id >= self.fail_after:
            raise DeviceTimeoutError("fake camera stopped")
        scene = self.display.current
        if scene is None:
            scene = np.zeros((self.profile.scene.rows, self.profile.scene.cols, 3), np.float32)
        dn = measure(self.sm, self.profile, scene, self.rng, self.exposure_us)
        self.frame_id += 1
        return RawFrame(mosaic_from_rgb(dn.astype(np.uint16)), time.monotonic_ns(), self.frame_id,
                        "BayerRG12", exposure_us=self.exposure_us, meta={"scene": scene})


def write_slit_recording(root: Any, profile: Profile, sm: SystemMatrices, rng: np.random.Generator | None,
                         validation: list[np.ndarray], dark: bool = True,
                         exposure_of: dict[str, float] | None = None, label_slits: bool = False,
                         hidden_gain: dict[str, float] | None = None, offset_dn: Any = 0.0) -> RecordingWriter:
    """A recording with (optional) dark frame, all row and column slits and validation scenes.

    Slit labels are meaningless unless ``label_slits`` (the calibration must not rely on them).
    ``exposure_of`` changes a frame's exposure and records it; ``hidden_gain`` scales a
    frame's signal without recording anything; ``offset_dn`` (scalar or ``R × S × 1`` map) is
    added to every frame (stray light, black level other than the profile's).
    """
    n, m = profile.scene.rows, profile.scene.cols
    w = RecordingWriter(root, profile)
    exposure_of = exposure_of or {}
    hidden_gain = hidden_gain or {}

    def add(scene: np.ndarray, label: str) -> None:
        exp = exposure_of.get(label, REFERENCE_EXPOSURE_US)
        effective = exp * hidden_gain.get(label, 1.0)
        dn = measure(sm, profile, scene, rng, effective, offset_dn)
        w.add(dn.astype(np.float32), scene, label=label, exposure_us=exp)

    if dark:
        add(np.zeros((n, m, 3), np.float32), "frame_dark")
    for i in range(n):
        x = np.zeros((n, m, 3), np.float32)
        x[i] = 1.0
        add(x, f"h{i}" if label_slits else f"f{len(w.frames)}")
    for j in range(m):
        x = np.zeros((n, m, 3), np.float32)
        x[:, j] = 1.0
        add(x, f"v{j}" if label_slits else f"f{len(w.frames)}")
    for k, x in enumerate(validation):
        add(x.astype(np.float32), f"val{k}")
    return w
