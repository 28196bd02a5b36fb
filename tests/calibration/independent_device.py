"""Slit-scan recordings of a device made WITHOUT the decoder's assumptions (test helper).

The calibration under test models every frame as ``Po X Qoᵀ + Pc X Qcᵀ``. The recordings here
are made by the exact simulator of CONTRACTS §4 (cos⁴ radiometry, sharp mask shadow, pixel
integration) with a *true* physics that differs from the profile (slightly different
distances, a shifted and slightly rotated mask), the contract's noise (Poisson, read noise,
rounding, clipping), one capture per scene (no averaging), and optional defects the
calibration must find: a dust speck (a dark, soft, round spot on the sensor image), a dim
sensor column, a ghost (a faint displaced copy of the whole sensor image, as a reflection
between the mask and the sensor's cover glass makes).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.formats.profiles import Profile, load_profile
from thintact_sdk.formats.recording import Recording, RecordingWriter
from thintact_sdk.reconstruction.filter_training import scene_for_channels
from thintact_sdk.reconstruction.mask_orientation import Orientation
from thintact_sdk.reconstruction.metrics import psnr
from thintact_sdk.simulation.noise import signal_to_dn
from thintact_sdk.simulation.scenes import gelsight, make_scene
from thintact_sdk.simulation.simulator import Simulator

TRUE_PHYSICS: dict[str, dict[str, Any]] = {
    "geometry": {"scene_to_mask_mm": 4.86, "mask_to_sensor_mm": 0.99},
    "mask_misalignment": {"angle_deg": 0.03, "dx_um": 3.0, "dy_um": -2.0},
}
"""How the real unit differs from its profile (all within assembly tolerances)."""


@dataclass(frozen=True)
class Dust:
    """A dust speck's shadow: transmission ``1 − depth·exp(−r²/2σ²)`` around ``(row, col)``."""

    row: int
    col: int
    sigma_px: float = 2.5
    depth: float = 0.5


@dataclass(frozen=True)
class DimColumn:
    """Sensor column ``col`` with ``gain`` (< 1) times the signal."""

    col: int
    gain: float = 0.85


@dataclass(frozen=True)
class Ghost:
    """A faint copy of the sensor image, ``strength`` times as bright, displaced by
    ``(rows, cols)`` sensor pixels (linear interpolation for fractions, dark outside)."""

    rows: float
    cols: float
    strength: float = 0.05

    def apply(self, signal: np.ndarray) -> np.ndarray:
        """``signal + strength · shift(signal)`` for an ``R × S × C`` signal."""
        from scipy import ndimage

        moved = ndimage.shift(signal, (self.rows, self.cols, 0), order=1, mode="constant", cval=0.0)
        return np.asarray(signal + self.strength * moved)


def small_profile(channels: tuple[str, ...] = ("R", "G", "B"), seed: int = 11,
                  rows: int = 64, cols: int = 80, scene: tuple[int, int] = (24, 32), k: int = 96) -> Profile:
    """virtual-mini's optics on a small sensor with a random φ of ``k`` cells (and a different φ_rows)."""
    d = load_profile("virtual-mini").contract_dict()
    rng = np.random.default_rng(seed)
    d["name"] = "independent-" + "".join(c.lower() for c in channels)
    d["sensor"] = {"rows": rows, "cols": cols, "pixel_pitch_um": 10.0, "channels": list(channels)}
    d["scene"] = {"rows": scene[0], "cols": scene[1], "pixel_pitch_um": 31.5}
    d["mask"] = {"feature_um": 20.0, "phi": rng.choice([-1, 1], k).tolist(),
                 "phi_rows": rng.choice([-1, 1], k).tolist()}
    d["physics"] = {}
    for key in ("camera", "display", "decoder", "light", "tactile", "calibration_limits"):
        d.pop(key, None)
    return Profile.model_validate(d)


def validation_scenes(n: int, m: int) -> list[tuple[str, np.ndarray]]:
    """The wizard's kinds of validation scenes (labels and ``N × M × 3`` display values)."""
    out = [("val_white", make_scene("white", n, m)), ("val_smooth_color", make_scene("smooth_color", n, m)),
           ("val_checker", make_scene("checker", n, m))]
    out += [(f"val_gelsight_{i}", gelsight(n, m, i)) for i in range(3)]
    return [(label, np.asarray(x, np.float32)) for label, x in out]


def _defect_gain(shape: tuple[int, int], defects: list[Dust | DimColumn | Ghost]) -> np.ndarray:
    gain = np.ones(shape)
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    for d in defects:
        if isinstance(d, Ghost):
            continue
        if isinstance(d, Dust):
            gain *= 1.0 - d.depth * np.exp(-((yy - d.row) ** 2 + (xx - d.col) ** 2) / (2 * d.sigma_px**2))
        else:
            gain[:, d.col] *= d.gain
    return gain


def write_recording(root: Path, profile: Profile, *, seed: int = 0, white_fraction: float = 0.7,
                    defects: list[Dust | DimColumn | Ghost] | None = None,
                    physics: dict[str, dict[str, Any]] | None = None) -> Recording:
    """Dark, white, every row and column slit, validation scenes: one noisy capture each.

    The white scene peaks at ``white_fraction`` of the sensor's range above black. The
    profile written with the recording is ``profile`` (the nominal design), not the truth.
    """
    truth = profile.with_physics(TRUE_PHYSICS if physics is None else physics)
    sim = Simulator(truth)
    n, m = profile.scene.rows, profile.scene.cols
    c = len(profile.sensor.channels)
    nz = profile.noise
    gain = white_fraction * (nz.saturation_dn - nz.black_level_dn) / float(
        np.max(sim.linear_batch(np.ones((1, n, m, c)))))
    defect = _defect_gain((profile.sensor.rows, profile.sensor.cols), defects or [])[..., None]
    ghosts = [d for d in defects or [] if isinstance(d, Ghost)]
    rng = np.random.default_rng(seed)
    w = RecordingWriter(root, profile)

    def add(scene: np.ndarray, label: str) -> None:
        signal = sim.predict_signal_dn(scene_for_channels(scene, c), gain)
        for ghost in ghosts:  # the reflection happens before the sensor's own defects
            signal = ghost.apply(signal)
        signal = signal * defect
        w.add(signal_to_dn(signal, nz, rng).astype(np.uint16), scene, label=label)

    zero = np.zeros((n, m, 3), np.float32)
    add(zero, "dark")
    add(np.ones((n, m, 3), np.float32), "white")
    for i in range(n):
        x = zero.copy()
        x[i] = 1.0
        add(x, f"hslit_{i:04d}")
    for j in range(m):
        x = zero.copy()
        x[:, j] = 1.0
        add(x, f"vslit_{j:04d}")
    for label, x in validation_scenes(n, m):
        add(x, label)
    return Recording(root)


HINDSIGHT_TAUS = np.geomspace(1e2, 1e7, 41)
"""τ grid (DN², 8 per decade) of the best-in-hindsight comparisons."""


def mean_psnr(out_dir: Path, rec: Recording) -> float:
    """Mean PSNR (dB) of ``thintact reconstruct``'s outputs in ``out_dir`` against the
    recording's non-black scenes."""
    values = []
    for i, fr in enumerate(rec.frames):
        truth = rec.scene(i)
        if truth is None or not truth.any():
            continue
        est = np.load(out_dir / f"{Path(fr.measurement).stem}.npy")
        values.append(psnr(np.clip(est, 0, 1), truth))
    return float(np.mean(values))


def best_in_hindsight(decoder: Any, frames: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """Best mean PSNR (dB) of a tunable decoder over :data:`HINDSIGHT_TAUS` on ``(signal,
    scene)`` frames, and its τ (DN²)."""
    best, best_tau = -np.inf, float("nan")
    for tau in HINDSIGHT_TAUS:
        decoder.set_tau(float(tau))
        v = float(np.mean([psnr(np.clip(decoder.decode(y), 0, 1), x) for y, x in frames]))
        if v > best:
            best, best_tau = v, float(tau)
    return best, best_tau


def mounted_profile(nominal: Profile, orientation: Orientation, angle_deg: float, dx_um: float,
                    dy_um: float, z_mm: float) -> Profile:
    """``nominal`` with its mask mounted in ``orientation`` (φ, φ_rows rewritten), turned by a
    further ``angle_deg``, shifted by ``(dx_um, dy_um)`` and at scene-to-mask distance ``z_mm``:
    the truth of a flat-field pose test."""
    d = nominal.contract_dict()
    px, py = orientation.apply(np.asarray(nominal.mask.phi), np.asarray(nominal.mask.rows_vector))
    d["mask"]["phi"], d["mask"]["phi_rows"] = px.tolist(), py.tolist()
    return Profile.model_validate(d).with_physics(
        {"mask_misalignment": {"dx_um": dx_um, "dy_um": dy_um, "angle_deg": angle_deg},
         "geometry": {"scene_to_mask_mm": z_mm}})
