"""Real2Sim on real presses, evaluated as the paper does (§VI-C): photometric stereo on
held-out real images against photometric stereo on their Real2Sim translations, each with
its own LUT calibration; plus a LUT calibrated on the simulation alone applied to the
translations (what Real2Sim is for: real images made to look like the simulation the LUT
came from).

Presses of a ``dataPack``-style ``.npz`` with annotated contact circles (Taxim's GelSight
pack): slopes are the annotated ball caps (see :mod:`thintact_sdk.tactile.calibration.gelsight_eval`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.tactile.calibration.gelsight_eval import (
    GELSIGHT_BALL_RADIUS_MM,
    GELSIGHT_MM_PER_PX,
    GelSightEvaluation,
    evaluate_images,
    load_pack,
    split_presses,
)
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT, calibrate_lut
from thintact_sdk.tactile.learning.domains import ball_presses, sensor_profile
from thintact_sdk.tactile.learning.translate import Real2SimTranslator


@dataclass
class Real2SimRow:
    """One row of the real-data table (held-out presses, inside 0.9 of the annotated circle)."""

    method: str
    slope_rms: float
    depth_rms_mm: float


def simulation_lut(rows: int, cols: int, mm_per_px: float, presses: int = 48,
                   ball_radius_mm: float = GELSIGHT_BALL_RADIUS_MM, bins: int = 24,
                   seed: int = 1) -> PhotometricLUT:
    """A LUT from the tactile simulation alone (exact slopes of simulated ball presses)."""
    rng = np.random.default_rng(seed)
    flat, scenes = ball_presses(sensor_profile(rows, cols, mm_per_px), presses, ball_radius_mm,
                                (0.4, 1.5), rng)
    valid = [(sc.depth_mm > 1e-3) | (rng.random(sc.depth_mm.shape) < 0.1) for sc in scenes]
    return calibrate_lut([sc.scene - flat.scene for sc in scenes], [sc.grad_x for sc in scenes],
                         [sc.grad_y for sc in scenes], valid, bins=bins,
                         meta={"source": "simulation"})


def evaluate_real2sim(
    pack_path: str | Path, translator: Real2SimTranslator, train: list[int] | None = None,
    bins: int = 24,
) -> tuple[list[Real2SimRow], dict[str, GelSightEvaluation]]:
    """The real-data table on the presses not in ``train``.

    ``train`` defaults to the presses the generator was trained on (its file records them);
    a test press that was in the generator's training set is refused.

    Returns
    -------
    (rows, evaluations)
        Rows ``real``, ``real2sim`` (LUT calibrated on translated training presses),
        ``real2sim+sim-lut`` (LUT from the simulation only), and the full evaluations.
    """
    pack = load_pack(pack_path)
    images = pack["imgs"].astype(np.float32) / 255.0
    f0 = pack["f0"].astype(np.float32) / 255.0
    seen = [int(i) for i in translator.meta.get("train_presses", [])]
    train, test = split_presses(len(images), seen if train is None and seen else train)
    leaked = sorted(set(test) & set(seen))
    if leaked:
        raise ThinTactError(
            f"presses {leaked[:5]}{'…' if len(leaked) > 5 else ''} were in the generator's "
            "training set: test on presses it never saw")
    translated = np.stack([translator(im) for im in images])
    ref_t = translator(f0)
    rows, cols = f0.shape[:2]
    evals = {
        "real": evaluate_images(pack, images, f0, train, bins),
        "real2sim": evaluate_images(pack, translated, ref_t, train, bins),
        "real2sim+sim-lut": evaluate_images(
            pack, translated, ref_t, train, bins,
            lut=simulation_lut(rows, cols, GELSIGHT_MM_PER_PX, bins=bins)),
    }
    table = [Real2SimRow(k, e.grad_rms, e.depth_rms_mm) for k, e in evals.items()]
    return table, evals
