"""Simulated presses with ground-truth force and slip, and the force/slip evaluation.

The tactile simulator draws the membrane (geometry, shading, markers) but knows no force.
Here the same press is also solved as an elastic contact (:mod:`thintact_sdk.tactile.simulation.elastic`,
an independent forward computation from the rigid interference, not from the rendered
image): the normal force from the Boussinesq contact solution, the tangential force and the
surface displacement from the generalised Cattaneo–Mindlin solution with friction μ. The
tangential displacement field moves the markers (on top of the simulator's normal-load
drag), so the markers show partial slip: the stick zone moves rigidly, the slip annulus lags.

A press is parametrised by ``stick_fraction`` = d*/d ∈ [0, 1]: 1 = no tangential load,
0 = gross sliding (Q = μP). Its true slip ratio is ``1 − A(d*)/A(d)``, the slipping share
of the contact area.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.ndimage import map_coordinates

from thintact_sdk.errors import InvalidValueError
from thintact_sdk.tactile.interpretation.force import ForceModel, fit_gain, fit_gains, loaded_core
from thintact_sdk.tactile.interpretation.grid import TactileParams
from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
from thintact_sdk.tactile.interpretation.slip import SLIPPING_RATIO, estimate_slip_ratio
from thintact_sdk.tactile.simulation.elastic import (
    Elastomer,
    solve_normal_contact,
    tangential_displacement,
)
from thintact_sdk.tactile.simulation.indenters import Indenter
from thintact_sdk.tactile.simulation.membrane import TactileScene, TactileSimulator

CLEARANCE_MM = 50.0
PRESS_MARGIN_MM = 5.0
"""Simulated presses keep their centre this far inside the field (mm)."""


@dataclass
class LoadedPress:
    """A simulated press and its mechanics.

    Attributes
    ----------
    scene
        Rendered scene and geometric ground truth (markers include the tangential field).
    force_n
        ``(3,)`` true [F_x, F_y, F_z] on the membrane (N).
    slip_ratio
        True slipping share of the contact area, in [0, 1].
    contact_area_mm2
        Elastic contact area (mm²).
    """

    scene: TactileScene
    force_n: np.ndarray
    slip_ratio: float
    contact_area_mm2: float


def interference_mm(
    sim: TactileSimulator, indenter: Indenter, depth_mm: float,
    center_mm: tuple[float, float], angle_deg: float,
) -> np.ndarray:
    """``N × M`` rigid interference d − gap (mm; negative where the indenter clears)."""
    x, y = sim.params.grid_mm()
    return indenter.indentation_mm(x, y, depth_mm + CLEARANCE_MM, center_mm, angle_deg) - CLEARANCE_MM


def simulate_loaded_press(
    sim: TactileSimulator,
    elastomer: Elastomer,
    indenter: Indenter,
    depth_mm: float,
    center_mm: tuple[float, float] = (0.0, 0.0),
    angle_deg: float = 0.0,
    shear_direction_rad: float = 0.0,
    stick_fraction: float = 1.0,
    friction: float = 1.0,
) -> LoadedPress:
    """Render a press with a tangential load and compute its true force and slip.

    Parameters
    ----------
    sim
        The tactile simulator (grid, shading, marker model).
    elastomer
        Material of the elastic solution.
    indenter, depth_mm, center_mm, angle_deg
        As :meth:`TactileSimulator.press`.
    shear_direction_rad
        Direction of the tangential load (atan2(y, x)).
    stick_fraction
        d*/d in [0, 1] (1: normal load only; 0: sliding).
    friction
        Coefficient of friction μ.
    """
    if not 0.0 <= stick_fraction <= 1.0:
        raise InvalidValueError(f"stick_fraction must be in [0, 1], got {stick_fraction}")
    p = sim.params
    full = solve_normal_contact(interference_mm(sim, indenter, depth_mm, center_mm, angle_deg),
                                p.mm_per_px, elastomer)
    stick = solve_normal_contact(
        interference_mm(sim, indenter, stick_fraction * depth_mm, center_mm, angle_deg),
        p.mm_per_px, elastomer)
    traction = friction * np.clip(full.pressure_mpa - stick.pressure_mpa, 0.0, None)
    direction = np.array([np.cos(shear_direction_rad), np.sin(shear_direction_rad)])
    ux, uy = tangential_displacement(traction * direction[0], traction * direction[1],
                                     p.mm_per_px, elastomer)
    base = sim.press(indenter, depth_mm, center_mm, angle_deg)
    rc = p.mm_to_px(base.marker_reference_mm).T
    moved = base.marker_positions_mm + np.stack(
        [map_coordinates(ux, rc, order=1, mode="nearest"),
         map_coordinates(uy, rc, order=1, mode="nearest")], axis=1)
    scene = TactileScene(sim.render(base.depth_mm, moved), base.depth_mm, base.grad_x,
                         base.grad_y, base.marker_reference_mm, moved)
    q = float(traction.sum()) * p.mm_per_px**2
    force = np.array([q * direction[0], q * direction[1], full.force_n])
    slip = 1.0 - stick.area_mm2 / full.area_mm2 if full.area_mm2 > 0 else 0.0
    return LoadedPress(scene, force, float(slip), full.area_mm2)


@dataclass
class ForceSlipEvaluation:
    """Force and slip estimates against the elastic ground truth on held-out presses.

    Attributes
    ----------
    normal_gain, normal_fill_gain, shear_gain
        Gains c_0, c_1, c_t fitted on the calibration presses.
    normal_rel_rms, shear_rel_rms
        RMS of (estimate − truth) / truth over the test presses (normal; shear magnitude
        where the true shear exceeds 10 % of μP).
    normal_range_n, shear_range_n
        (min, max) true forces of the test presses (N).
    shear_direction_deg, shear_direction_median_deg
        RMS and median absolute error of the shear direction (degrees).
    slip_mae, slip_rms
        Mean absolute and RMS error of the slip ratio.
    slip_incipient_detected
        Share of test presses with true slip ratio in [0.2, 0.8] flagged as slipping
        (estimate ≥ 0.15) — incipient slip detection.
    slip_false_alarm
        Share of presses without tangential load whose estimate is ≥ 0.15.
    presses
        Test presses per row (calibration presses are as many again, other seeds).
    rows
        Per-press (indenter, depth, true/estimated Fz, |Fxy|, slip).
    """

    normal_gain: float
    normal_fill_gain: float
    shear_gain: float
    normal_rel_rms: float
    shear_rel_rms: float
    normal_range_n: tuple[float, float]
    shear_range_n: tuple[float, float]
    shear_direction_deg: float
    shear_direction_median_deg: float
    slip_mae: float
    slip_rms: float
    slip_incipient_detected: float
    slip_false_alarm: float
    presses: int
    rows: list[dict[str, float | str]]


def _press_area(p: TactileParams) -> tuple[float, float]:
    """Half width and height (mm) of the region press centres are drawn from."""
    half_w = p.cols / 2 * p.mm_per_px - PRESS_MARGIN_MM
    half_h = p.rows / 2 * p.mm_per_px - PRESS_MARGIN_MM
    if half_w < 0 or half_h < 0:
        from thintact_sdk.errors import ThinTactError

        raise ThinTactError(
            f"the force/slip evaluation presses indenters up to 16 mm wide, centred "
            f"{PRESS_MARGIN_MM:g} mm inside the field; this profile's field is "
            f"{p.cols * p.mm_per_px:.1f} × {p.rows * p.mm_per_px:.1f} mm (use virtual-finger)"
        )
    return half_w, half_h


def _press_set(sim: TactileSimulator, elastomer: Elastomer, count: int, seed: int,
               indenters: Sequence[Indenter]) -> list[tuple[Indenter, float, LoadedPress]]:
    rng = np.random.default_rng(seed)
    half_w, half_h = _press_area(sim.params)
    out = []
    for k in range(count):
        ind = indenters[k % len(indenters)]
        depth = float(rng.uniform(0.3, 1.0))
        centre = (float(rng.uniform(-half_w, half_w)), float(rng.uniform(-half_h, half_h)))
        stick = 1.0 if k % 4 == 0 else float(rng.uniform(0.05, 0.95))
        press = simulate_loaded_press(sim, elastomer, ind, depth, centre,
                                      float(rng.uniform(0, 180)),
                                      float(rng.uniform(-np.pi, np.pi)), stick)
        out.append((ind, depth, press))
    return out


def _unit_gain_estimates(
    interp: TactileInterpreter, press: LoadedPress, elastomer: Elastomer
) -> tuple[np.ndarray, np.ndarray, float | None]:
    """The normal features (c_0, c_1 multiply them), the shear with unit gain (c_t
    multiplies it) and the slip ratio of one press."""
    frame = interp.interpret(press.scene.scene)
    p = interp.params
    args = (frame.depth_mm, p.mm_per_px, p.contact_threshold_mm, interp.tracker.reference_mm,
            frame.marker_displacements_mm)
    model = ForceModel(elastomer, 0.0, 0.0, 1.0)
    core = loaded_core(frame.depth_mm, p.mm_per_px, p.contact_threshold_mm)
    normal = np.array(model.normal_features(core) if core is not None else (0.0, 0.0))
    return normal, model.estimate(*args)[:2], estimate_slip_ratio(*args)


def evaluate_force_slip(
    profile: object, presses: int = 12, seed: int = 0, elastomer: Elastomer | None = None,
) -> ForceSlipEvaluation:
    """Fit c_0, c_1, c_t on simulated presses (balls of 3 and 8 mm radius, a 2.5 mm cylinder,
    a 5 × 3 mm prism) and test them and the slip signal on other presses (balls of 4 and
    6 mm, the default cylinder and prism).

    The scenes are interpreted directly (scene level, no lensless decoding) with the
    profile's simulated LUT, so the figures measure the mechanics model, not the imaging.

    Parameters
    ----------
    profile
        A :class:`~thintact_sdk.formats.profiles.Profile` with markers (``virtual-finger``).
    presses
        Test presses (the calibration uses as many, from other seeds).
    """
    from thintact_sdk.formats.profiles import Profile
    from thintact_sdk.tactile.calibration.ball_press import scene_level_lut
    from thintact_sdk.tactile.simulation.indenters import ChamferedPrism, Cylinder, Sphere

    assert isinstance(profile, Profile)
    el = elastomer or Elastomer.from_profile(profile)
    sim = TactileSimulator.for_profile(profile)
    _press_area(sim.params)
    interp = TactileInterpreter(profile, scene_level_lut(profile))
    shapes = [Sphere(3.0), Cylinder(2.5, 6.0), Sphere(8.0), ChamferedPrism(5.0, 3.0, 0.7)]
    others = [Sphere(4.0), Cylinder(), ChamferedPrism(), Sphere(6.0)]

    def measure(items: list[tuple[Indenter, float, LoadedPress]]) -> list[tuple[Any, ...]]:
        res = []
        for ind, depth, press in items:
            interp.set_reference(sim.flat().scene)
            normal, shear, slip = _unit_gain_estimates(interp, press, el)
            res.append((ind, depth, press, normal, shear, slip, press.force_n))
        return res

    train = measure(_press_set(sim, el, presses, seed, shapes))
    test = measure(_press_set(sim, el, presses, seed + 1000, others))
    c0, c1 = fit_gains([r[3] for r in train], [r[6][2] for r in train])
    sheared = [r for r in train if np.hypot(*r[6][:2]) > 0.1 * r[6][2]]
    ct = fit_gain([np.hypot(*r[4]) for r in sheared], [np.hypot(*r[6][:2]) for r in sheared])
    rows: list[dict[str, float | str]] = []
    n_err, s_err, d_err, slip_err = [], [], [], []
    detected, incipient, alarms, unloaded = 0, 0, 0, 0
    for ind, depth, press, normal, shear, slip, truth in test:
        fz, fxy = max(0.0, c0 * normal[0] + c1 * normal[1]), ct * shear
        n_err.append((fz - truth[2]) / truth[2])
        t_shear = float(np.hypot(*truth[:2]))
        dir_err = float("nan")
        if t_shear > 0.1 * truth[2]:
            s_err.append((float(np.hypot(*fxy)) - t_shear) / t_shear)
            ang = np.arctan2(fxy[1], fxy[0]) - np.arctan2(truth[1], truth[0])
            dir_err = float(np.rad2deg(np.angle(np.exp(1j * ang))))
            d_err.append(dir_err)
        est_slip = float("nan") if slip is None else slip
        if np.isfinite(est_slip):
            slip_err.append(est_slip - press.slip_ratio)
        if 0.2 <= press.slip_ratio <= 0.8:
            incipient += 1
            detected += int(est_slip >= SLIPPING_RATIO)
        if t_shear == 0.0:
            unloaded += 1
            alarms += int(est_slip >= SLIPPING_RATIO)
        rows.append({"indenter": ind.name, "depth_mm": depth, "fz_true_n": float(truth[2]),
                     "fz_est_n": float(fz), "shear_true_n": t_shear,
                     "shear_est_n": float(np.hypot(*fxy)), "shear_direction_error_deg": dir_err,
                     "slip_true": press.slip_ratio,
                     "slip_est": est_slip})
    rms = lambda v: float(np.sqrt(np.mean(np.square(v)))) if len(v) else float("nan")  # noqa: E731
    fz_true = [float(r["fz_true_n"]) for r in rows]
    sh_true = [float(r["shear_true_n"]) for r in rows if float(r["shear_true_n"]) > 0]
    return ForceSlipEvaluation(
        normal_gain=float(c0), normal_fill_gain=float(c1), shear_gain=ct,
        normal_rel_rms=rms(n_err), shear_rel_rms=rms(s_err),
        normal_range_n=(min(fz_true), max(fz_true)),
        shear_range_n=(min(sh_true), max(sh_true)) if sh_true else (0.0, 0.0),
        shear_direction_deg=rms(d_err),
        shear_direction_median_deg=float(np.median(np.abs(d_err))) if d_err else float("nan"),
        slip_mae=float(np.mean(np.abs(slip_err))) if slip_err else float("nan"),
        slip_rms=rms(slip_err),
        slip_incipient_detected=detected / incipient if incipient else float("nan"),
        slip_false_alarm=alarms / unloaded if unloaded else float("nan"),
        presses=presses, rows=rows,
    )
