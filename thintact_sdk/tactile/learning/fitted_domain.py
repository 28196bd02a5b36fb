"""The sim domain of a simulation fitted to the sensor (``thintact diagnose-tactile``'s
``fitted_tactile.yaml``), and the choice between it and the SDK's nominal simulation
(:mod:`.domains`) for Real2Sim training.

Kept apart from :mod:`.domains` because the diagnosis reads real presses through it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.tactile.learning.domains import (
    RealPresses,
    sensor_profile,
    simulated_presses,
    with_camera_noise,
)


def fitted_section(section_file: str | Path, frame: tuple[int, int] | None = None) -> dict:
    """Read ``diagnose-tactile``'s ``fitted_tactile.yaml``: at most
    :data:`~thintact_sdk.formats.profiles.MAX_PROFILE_BYTES`, read by
    :mod:`thintact_sdk.formats.safe_yaml` (core-schema tags only, bounded aliases, no recursive
    alias, duplicate or merge key) and checked whole by
    :func:`~thintact_sdk.diagnosis.tactile.report.model_from_section` (shapes, finite numbers,
    physical ranges; lengths against ``frame``, ``(rows, cols)``, when given).

    Raises
    ------
    ThinTactError
        One line naming the file: unreadable, too large, not UTF-8, not YAML, too deeply
        nested, or not a valid fitted section (naming the field).
    """
    from thintact_sdk.diagnosis.tactile.report import model_from_section
    from thintact_sdk.formats import safe_yaml
    from thintact_sdk.formats.profiles import MAX_PROFILE_BYTES

    p = Path(section_file)
    section = safe_yaml.read_file(p, "fitted tactile section", ThinTactError, MAX_PROFILE_BYTES)
    if not isinstance(section, dict):
        raise ThinTactError(f"{p}: not a fitted tactile section (a YAML mapping with 'tactile')")
    try:
        model_from_section(section, frame)
    except ThinTactError as exc:
        raise ThinTactError(f"{p}: {exc}") from None
    return section


def fitted_simulated_presses(
    section_file: str | Path,
    reference: np.ndarray,
    count: int,
    ball_radius_mm: float,
    mm_per_px: float,
    depth_range_mm: tuple[float, float] = (0.2, 1.8),
    seed: int = 0,
    noise_std: float = 0.01,
) -> np.ndarray:
    """The sim domain of a simulation fitted to this sensor: ``thintact diagnose-tactile``'s
    ``fitted_tactile.yaml`` (lights, lobe, elastomer blur, illumination field, texture, camera
    response), its no-contact frame as image 0 and ``count`` marker-free ball presses at
    random places and depths, each with Gaussian camera noise of ``noise_std``.

    ``reference`` is the real no-contact frame (``H × W × 3`` in [0, 1]) whose texture the
    fitted background carries.

    Returns
    -------
    numpy.ndarray
        ``(count + 1) × H × W × 3`` float32 in [0, 1].

    Raises
    ------
    ThinTactError
        Naming the file: unreadable, not YAML, not a fitted section (naming the field; its
        lengths checked against ``reference``'s grid), or fitted at another pixel size than
        ``mm_per_px``.
    """
    from thintact_sdk.diagnosis.tactile.correction import fitted_images
    from thintact_sdk.diagnosis.tactile.report import model_from_section

    p = Path(section_file)
    frame = (int(reference.shape[0]), int(reference.shape[1]))
    section = fitted_section(p, frame)
    model = model_from_section(section, frame)
    fitted_mm = float(section["tactile"]["mm_per_px"])
    if abs(fitted_mm / mm_per_px - 1.0) > 1e-3:
        raise ThinTactError(f"{p}: fitted at {fitted_mm} mm/px, the real images are at "
                            f"{mm_per_px:g} mm/px")
    flat, images, _gx, _gy = fitted_images(model, reference.astype(np.float64), ball_radius_mm,
                                           mm_per_px, count, depth_range_mm, seed)
    return with_camera_noise([flat] + images, noise_std, np.random.default_rng(seed))


def sim_domain(real: RealPresses, count: int, ball_radius_mm: float, mm_per_px: float,
               seed: int = 0, fitted_section: str | Path | None = None) -> np.ndarray:
    """The sim domain for ``real``'s grid: the SDK's nominal tactile simulation
    (:func:`simulated_presses`) or, with ``fitted_section``, the simulation
    ``diagnose-tactile`` fitted to this sensor (:func:`fitted_simulated_presses`)."""
    if fitted_section is not None:
        return fitted_simulated_presses(fitted_section, real.reference, count, ball_radius_mm,
                                        mm_per_px, seed=seed)
    rows, cols = real.reference.shape[:2]
    return simulated_presses(sensor_profile(rows, cols, mm_per_px), count, ball_radius_mm,
                             seed=seed)
