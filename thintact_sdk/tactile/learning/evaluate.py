"""Real2Sim on real presses, evaluated as the paper does (§VI-C): photometric stereo on
held-out real images against photometric stereo on their Real2Sim translations, each with
its own LUT calibration; plus a LUT calibrated on the simulation alone applied to the
translations (what Real2Sim is for: real images made to look like the simulation the LUT
came from).

Presses of a ``dataPack``-style ``.npz`` with annotated contact circles (Taxim's GelSight
pack): slopes are the annotated ball caps (see :mod:`thintact_sdk.tactile.calibration.gelsight_eval`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

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
        ``real2sim+sim-lut`` (LUT from the nominal simulation only) or, for a generator trained
        against a fitted simulation, ``real2sim+fitted-sim-lut`` (LUT from that simulation
        only), and the full evaluations.
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
    }
    section = fitted_section_of(translator)
    if section is None:
        evals["real2sim+sim-lut"] = evaluate_images(
            pack, translated, ref_t, train, bins,
            lut=simulation_lut(rows, cols, GELSIGHT_MM_PER_PX, bins=bins))
    else:  # the generator maps onto the fitted simulation: its LUT (exact simulated slopes)
        from thintact_sdk.diagnosis.tactile.correction import fitted_simulation_lut
        from thintact_sdk.diagnosis.tactile.report import model_from_section

        evals["real2sim+fitted-sim-lut"] = evaluate_images(
            pack, translated, ref_t, train, bins,
            lut=fitted_simulation_lut(model_from_section(section, (rows, cols)), f0.astype(np.float64),
                                      GELSIGHT_BALL_RADIUS_MM, GELSIGHT_MM_PER_PX, bins))
    table = [Real2SimRow(k, e.grad_rms, e.depth_rms_mm) for k, e in evals.items()]
    return table, evals


def translate_pack(pack: Any, translator: Real2SimTranslator) -> Any:
    """A :class:`~thintact_sdk.tactile.calibration.press_pack.PressPack` whose reference and
    presses are ``translator``'s Real2Sim translations (uint8 RGB as the real pack; names,
    pixel size, ball radius and annotation kept)."""

    def u8(image: np.ndarray) -> np.ndarray:
        return np.clip(np.rint(translator(image) * 255.0), 0, 255).astype(np.uint8)

    images = np.stack([u8(pack.image(i)) for i in range(len(pack.images))])
    return replace(pack, images=images, reference=u8(pack.reference_image()),
                   meta={**pack.meta, "real2sim": str(translator.meta.get("sim_model") or "nominal")})


def fitted_section_of(translator: Real2SimTranslator) -> dict[str, Any] | None:
    """The fitted tactile section the generator's sim domain was rendered from (stored in
    the generator file by ``real2sim train --sim-model``), or None for the nominal simulation."""
    section = translator.meta.get("sim_model_section")
    return section if isinstance(section, dict) else None


def ball_figures(
    pack_path: str | Path,
    translator: Real2SimTranslator,
    ball_radius_mm: float | None = None,
    mm_per_px: float | None = None,
    model: str = "auto",
    stage: Callable[[str], None] | None = None,
) -> dict[str, dict[str, Any]]:
    """Issue 29's annotation-free figures (:mod:`~thintact_sdk.tactile.calibration.ball_eval`:
    sphere radius of the caps, contact ratio, depth and slope RMS against the fixed-radius ball)
    on the presses the generator never saw, each row calibrated on the presses it trained on
    (what ``thintact tactile evaluate`` does):

    * ``real``: the real images, calibrated from them and the ball radius;
    * ``real2sim``: the translations, calibrated from the translated training presses;
    * with a generator trained against a fitted simulation (``real2sim train --sim-model``),
      also ``real2sim+fitted-sim-lut`` (the translations through a LUT calibrated on the
      fitted simulation's exact slopes: no real ground truth at all) and, for comparison,
      ``real+fitted-sim-lut`` (the same LUT on the real images).

    Returns
    -------
    dict
        Row name → :func:`~thintact_sdk.tactile.calibration.press_pack.evaluate_pack`'s result
        (without the LUT object).
    """
    from thintact_sdk.diagnosis.tactile.correction import fitted_simulation_lut
    from thintact_sdk.diagnosis.tactile.report import model_from_section
    from thintact_sdk.tactile.calibration.press_pack import evaluate_pack, load_press_pack

    say = stage or (lambda _m: None)
    pack = load_press_pack(pack_path)
    radius = float(ball_radius_mm or pack.ball_radius_mm or translator.meta.get("ball_radius_mm")
                   or GELSIGHT_BALL_RADIUS_MM)
    mm = float(mm_per_px or pack.mm_per_px or translator.meta.get("mm_per_px") or GELSIGHT_MM_PER_PX)
    seen = [int(i) for i in translator.meta.get("train_presses", [])]
    if not seen:
        raise ThinTactError("the generator file does not record its training presses")
    say("translating the presses")
    translated = translate_pack(pack, translator)
    rows: dict[str, dict[str, Any]] = {}
    for name, images in (("real", pack), ("real2sim", translated)):
        say(f"{name}: calibrating on the {len(seen)} training presses")
        rows[name] = evaluate_pack(images, radius, mm, seen, model, stage=say)
    section = fitted_section_of(translator)
    if section is not None:
        fitted = model_from_section(section, pack.reference.shape[:2])
        for name, images in (("real2sim+fitted-sim-lut", translated), ("real+fitted-sim-lut", pack)):
            say(f"{name}: LUT of the fitted simulation")
            lut = fitted_simulation_lut(fitted, pack.reference_image().astype(np.float64), radius, mm)
            rows[name] = evaluate_pack(images, radius, mm, seen, lut=lut, stage=say)
    for res in rows.values():
        res.pop("lut", None)
    return rows
