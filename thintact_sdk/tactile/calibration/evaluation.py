"""Accuracy of a sensor's tactile output against simulated ground truth (paper §VI-C).

The sensor is driven by showing tactile scenes (``show(scene)``: for the virtual camera,
its scene slot) and reading what comes out of the full path (camera → measurement →
decoder → interpreter). Depth error follows the paper: per image, the RMS over the pixels
where the ground-truth depth exceeds the contact threshold, then the mean over images.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
from thintact_sdk.tactile.simulation.indenters import ChamferedPrism, Indenter, Sphere
from thintact_sdk.tactile.simulation.membrane import TactileScene, TactileSimulator

Show = Callable[[np.ndarray | None], None]
Progress = Callable[[int, int], None]

PAPER_INDENTERS: dict[str, Indenter] = {
    "chamfered prism": ChamferedPrism(length_mm=6.0, width_mm=4.0, chamfer_mm=1.0),
    "4 mm sphere": Sphere(radius_mm=2.0),
}
PAPER_DEPTHS_MM = (0.25, 0.50, 0.75, 1.00)
# paper Table II: (real, Real2Sim) RMS depth error in mm
PAPER_TABLE_MM: dict[tuple[str, float], tuple[float, float]] = {
    ("chamfered prism", 0.25): (0.248, 0.065),
    ("chamfered prism", 0.50): (0.341, 0.090),
    ("chamfered prism", 0.75): (0.407, 0.098),
    ("chamfered prism", 1.00): (0.447, 0.142),
    ("4 mm sphere", 0.25): (0.262, 0.169),
    ("4 mm sphere", 0.50): (0.324, 0.172),
    ("4 mm sphere", 0.75): (0.365, 0.156),
    ("4 mm sphere", 1.00): (0.365, 0.109),
}


@dataclass
class DepthRow:
    """Depth error of one indenter at one press depth.

    Attributes
    ----------
    indenter, depth_mm
        What was pressed and how deep.
    rms_mm
        Mean over presses of the per-image RMS depth error through the sensor, mm.
    rms_scene_mm
        The same presses interpreted straight from the simulated scene (no lensless
        imaging) with a LUT calibrated on simulated scenes: the photometric-stereo share of
        the error, mm.
    presses
        Number of presses (random positions and rotations).
    """

    indenter: str
    depth_mm: float
    rms_mm: float
    rms_scene_mm: float
    presses: int


@dataclass
class MarkerResult:
    """Marker displacement error through the sensor.

    Attributes
    ----------
    rms_mm
        RMS over tracked markers and presses of (tracked − true) displacement, mm.
    tracked_fraction
        Share of reference markers tracked in the final frames.
    max_true_mm
        Largest true displacement in the test, mm.
    direction_error_deg
        Mean absolute error of the shear direction, degrees (180 when no shear was seen).
    direction_errors_deg
        The same per press.
    """

    rms_mm: float
    tracked_fraction: float
    max_true_mm: float
    direction_error_deg: float
    direction_errors_deg: list[float]


def depth_rms(estimate_mm: np.ndarray, truth_mm: np.ndarray, threshold_mm: float) -> float:
    """RMS of ``estimate − truth`` over pixels where ``truth > threshold`` (paper's area)."""
    m = truth_mm > threshold_mm
    if not m.any():
        return float("nan")
    return float(np.sqrt(np.mean((estimate_mm[m] - truth_mm[m]) ** 2)))


def _random_pose(rng: np.random.Generator, sim: TactileSimulator, margin_mm: float) -> tuple:
    p = sim.params
    hx = p.cols / 2 * p.mm_per_px - margin_mm
    hy = p.rows / 2 * p.mm_per_px - margin_mm
    return (float(rng.uniform(-hx, hx)), float(rng.uniform(-hy, hy))), float(rng.uniform(0, 180))


def set_reference(sensor: object, show: Show, sim: TactileSimulator, frames: int = 4) -> None:
    """Show the unloaded membrane and make the mean of ``frames`` images the reference."""
    show(sim.flat().scene)
    read_image = sensor.read_image  # type: ignore[attr-defined]
    acc = read_image().astype(np.float64)
    for _ in range(frames - 1):
        acc += read_image()
    sensor.reset_reference()  # type: ignore[attr-defined]
    sensor.interpreter.set_reference((acc / frames).astype(np.float32))  # type: ignore[attr-defined]


def evaluate_depth(
    sensor: object,
    show: Show,
    indenters: dict[str, Indenter] | None = None,
    depths_mm: tuple[float, ...] = PAPER_DEPTHS_MM,
    presses: int = 3,
    seed: int = 0,
    progress: Progress | None = None,
) -> list[DepthRow]:
    """The paper's depth-accuracy table through ``sensor``.

    Parameters
    ----------
    sensor
        An opened :class:`~thintact_sdk.device.sensor.Sensor` whose camera shows what ``show`` sets.
    show
        Puts a tactile scene (``N × M × 3``) in front of the camera (None: back to default).
    indenters
        Name → indenter (default: the paper's chamfered prism and 4 mm sphere).
    depths_mm
        Press depths.
    presses
        Random positions/rotations per indenter and depth.
    """
    indenters = PAPER_INDENTERS if indenters is None else indenters
    profile = sensor.profile  # type: ignore[attr-defined]
    sim = TactileSimulator.for_profile(profile)
    thr = sim.params.contact_threshold_mm
    rng = np.random.default_rng(seed)
    set_reference(sensor, show, sim)
    from thintact_sdk.tactile.calibration.ball_press import scene_level_lut

    scene_interp = TactileInterpreter(profile, scene_level_lut(profile, seed=seed))
    scene_interp.set_reference(sim.flat().scene)
    rows: list[DepthRow] = []
    total, done = len(indenters) * len(depths_mm) * presses, 0
    for name, indenter in indenters.items():
        for depth in depths_mm:
            errs, errs_scene = [], []
            for _ in range(presses):
                center, angle = _random_pose(rng, sim, 3.0)
                truth = sim.press(indenter, depth, center, angle)
                show(truth.scene)
                frame = sensor.read()  # type: ignore[attr-defined]
                errs.append(depth_rms(frame.depth_mm, truth.depth_mm, thr))
                errs_scene.append(depth_rms(scene_interp.depth_from_image(truth.scene),
                                            truth.depth_mm, thr))
                done += 1
                if progress is not None:
                    progress(done, total)
            rows.append(DepthRow(name, depth, float(np.nanmean(errs)),
                                 float(np.nanmean(errs_scene)), presses))
    show(None)
    return rows


def marker_errors(interp: TactileInterpreter, frame_disp: np.ndarray, truth: TactileScene
                  ) -> tuple[np.ndarray, int]:
    """Per-marker displacement errors (``K' × 2`` mm) of a tracked frame against the truth,
    matching each tracked reference marker to the nearest true one (not by index: a marker
    missed in the reference shifts the order), and how many markers were compared."""
    ref = interp.reference_markers_mm
    if len(ref) == 0:
        return np.zeros((0, 2)), 0
    dist, j = cKDTree(truth.marker_reference_mm).query(ref)
    ok = np.isfinite(frame_disp[:, 0]) & (dist < 0.3 * interp.params.marker_pitch_mm)
    return frame_disp[ok] - truth.marker_displacements_mm[j[ok]], int(ok.sum())


def evaluate_markers(
    sensor: object,
    show: Show,
    presses: int = 6,
    max_shear_mm: float = 0.3,
    steps: int = 3,
    seed: int = 1,
    progress: Progress | None = None,
) -> MarkerResult:
    """Marker displacement error through ``sensor``: a 4 mm sphere pressed 0.5 mm at random
    places, then sheared in ``steps`` frames up to a random shear ≤ ``max_shear_mm``
    (tracking cascades frame to frame)."""
    profile = sensor.profile  # type: ignore[attr-defined]
    sim = TactileSimulator.for_profile(profile)
    rng = np.random.default_rng(seed)
    errors, tracked, expected, max_true, dir_err = [], 0, 0, 0.0, []
    for k in range(presses):
        set_reference(sensor, show, sim)
        interp = sensor.interpreter  # type: ignore[attr-defined]
        center, _ = _random_pose(rng, sim, 3.0)
        magnitude = rng.uniform(0.5, 1.0) * max_shear_mm
        angle = rng.uniform(-np.pi, np.pi)
        shear = np.array([np.cos(angle), np.sin(angle)]) * magnitude
        for s in range(1, steps + 1):
            truth = sim.press(Sphere(2.0), 0.5, center, 0.0, tuple(shear * s / steps))
            show(truth.scene)
            frame = sensor.read()  # type: ignore[attr-defined]
        err, n_ok = marker_errors(interp, frame.marker_displacements_mm, truth)
        errors.append(err)
        tracked += n_ok
        expected += len(truth.marker_reference_mm)
        max_true = max(max_true, float(np.abs(truth.marker_displacements_mm).max()))
        if np.isfinite(frame.shear_direction_rad):
            d = np.angle(np.exp(1j * (frame.shear_direction_rad - angle)))
            dir_err.append(abs(float(np.degrees(d))))
        else:
            dir_err.append(180.0)
        if progress is not None:
            progress(k + 1, presses)
    show(None)
    all_err = np.concatenate(errors) if errors else np.zeros((0, 2))
    rms = float(np.sqrt(np.mean(all_err**2))) if len(all_err) else float("nan")
    return MarkerResult(rms, tracked / max(expected, 1), max_true, float(np.mean(dir_err)),
                        [round(e, 1) for e in dir_err])
