"""The simulator's diffraction paths against the converged brute-force Fresnel reference
(issue 17; :mod:`thintact_sdk.simulation.reference_fresnel`). Prints Markdown tables.

Device "16×20": 16×20 sensor pixels of 20 µm, 6×8 scene pixels of 60 µm, 24×24 cells of
20 µm, z = 1.0 mm, d = 0.3 mm (tests/simulator/test_sim_diffraction_bruteforce.py's
``DEVICE``), eight sensor pixels (corners, centre, edges) × three scene pixels. Device
"3×3": the refraction tests' 3×3-sensor / 2×3-scene window (25 µm cells; 20 µm, K = 40 with
a rotation), every pixel pair. λ = 530 nm unless the case says otherwise.

Columns: simulator vs the reference at the finer step; the reference's change between the
two steps (its convergence); the same diffraction without the case's effect vs the reference
(the size of what the effect changes); wall times (simulator build + forward, reference).

    python tools/measure_diffraction_reference.py [--quick] [--subsampling]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.simulator.sim_helpers import rel_rms, tiny_profile  # noqa: E402
from thintact_sdk.simulation.reference_fresnel import (  # noqa: E402
    crossing_grid_reference_kernel,
    ray_offset_reference_kernel,
    subsampled_reference_kernel,
)
from thintact_sdk.simulation.simulator import Simulator  # noqa: E402

BIG: dict[str, Any] = dict(rows=16, cols=20, pitch_um=20.0, scene_rows=6, scene_cols=8,
                           scene_pitch_um=60.0, feature_um=20.0, k=24, z_mm=1.0, d_mm=0.3)
BIG_SENSOR = np.array([0, 9, 19, 7 * 20 + 9, 8 * 20 + 10, 15 * 20, 15 * 20 + 19, 3 * 20 + 15])
BIG_SCENE = np.array([0, 2 * 8 + 3, 5 * 8 + 7])
WIN: dict[str, Any] = dict(rows=3, cols=3, scene_rows=2, scene_cols=3, pitch_um=20.0,
                           scene_pitch_um=60.0, feature_um=25.0, z_mm=1.0, d_mm=0.3)
WIN_ROT: dict[str, Any] = dict(WIN, feature_um=20.0, k=40)
REFR = {"refraction": {"n_scene_side": 1.4}}


def case_list() -> list[tuple[str, dict, dict, dict, str, float]]:
    """(name, physics without diffraction, the same without the effect under test, device,
    "big"/"win", wavelength)."""
    mis = "mask_misalignment"
    shift = {mis: {"dx_um": 7.0, "dy_um": -5.0}}
    return [
        ("alone, 625 nm", {}, {}, BIG, "big", 625.0),
        ("alone, 530 nm", {}, {}, BIG, "big", 530.0),
        ("alone, 465 nm", {}, {}, BIG, "big", 465.0),
        ("+ rotation 0.05°", {mis: {"angle_deg": 0.05}}, {}, BIG, "big", 530.0),
        ("+ rotation 0.35°", {mis: {"angle_deg": 0.35}}, {}, BIG, "big", 530.0),
        ("+ rotation 1°", {mis: {"angle_deg": 1.0}}, {}, BIG, "big", 530.0),
        ("+ rotation 1° + shift (−4, 2) µm",
         {mis: {"angle_deg": 1.0, "dx_um": -4.0, "dy_um": 2.0}}, {}, BIG, "big", 530.0),
        ("+ shift (7, −5) µm", shift, {}, BIG, "big", 530.0),
        ("+ leakage 0.1 + angular p = 2", {"mask_leakage": {"transmittance": 0.1},
                                           "pixel_angular_response": {"exponent": 2.0}},
         {}, BIG, "big", 530.0),
        ("+ geometry z 1.1, d 0.35 mm", {"geometry": {"scene_to_mask_mm": 1.1,
                                                      "mask_to_sensor_mm": 0.35}},
         {}, BIG, "big", 530.0),
        ("+ refraction n = 1.4", REFR, {}, BIG, "big", 530.0),
        ("+ refraction + rotation 0.35°", {**REFR, mis: {"angle_deg": 0.35}}, REFR, BIG, "big",
         530.0),
        ("+ refraction n = 1.4", REFR, {}, WIN, "win", 530.0),
        ("+ refraction + shift (7, −5) µm", {**REFR, **shift}, REFR, WIN, "win", 530.0),
        ("+ refraction + rotation 0.35°", {**REFR, mis: {"angle_deg": 0.35}}, REFR,
         WIN_ROT, "win", 530.0),
        ("+ refraction + rotation 2° + shift (−4, 2) µm",
         {**REFR, mis: {"angle_deg": 2.0, "dx_um": -4.0, "dy_um": 2.0}}, REFR,
         WIN_ROT, "win", 530.0),
    ]


def pixels(kind: str, device: dict) -> tuple[np.ndarray, np.ndarray]:
    if kind == "big":
        return BIG_SENSOR, BIG_SCENE
    return (np.arange(device["rows"] * device["cols"]),
            np.arange(device["scene_rows"] * device["scene_cols"]))


def simulated(physics: dict, device: dict, sens: np.ndarray, scen: np.ndarray,
              channel: int) -> np.ndarray:
    x = np.zeros((scen.size, device["scene_rows"], device["scene_cols"], 3))
    for i, j in enumerate(scen):
        x[i].reshape(-1, 3)[j] = 1.0
    y = Simulator(tiny_profile(physics, **device)).forward_batch(x)[..., channel]
    return y.reshape(scen.size, -1)[:, sens].T


def reference(physics: dict, device: dict, sens: np.ndarray, scen: np.ndarray, lam: float,
              step_um: float, quick: bool) -> np.ndarray:
    prof = tiny_profile(physics, **device)
    if "refraction" in physics:
        return ray_offset_reference_kernel(prof, lam, step_um, 24 if quick else 40, sens, scen)
    return crossing_grid_reference_kernel(prof, lam, step_um, 3, sens, scen)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="coarser reference steps (0.2/0.1 µm)")
    ap.add_argument("--subsampling", action="store_true",
                    help="also show plain 4-D sub-sampling converging (alone, 530 nm)")
    ap.add_argument("--only", default="", help="only the cases whose name contains this text")
    args = ap.parse_args()
    steps = (0.2, 0.1) if args.quick else (0.1, 0.05)
    wl = [625.0, 530.0, 465.0]
    print(f"| case | device | sim vs ref ({steps[1]} µm) | ref {steps[0]}→{steps[1]} µm | "
          "without the effect vs ref | sim s | ref s |")
    print("|---|---|---|---|---|---|---|")
    for name, extra, base, device, kind, lam in case_list():
        if args.only and (args.only not in f"{name} {'16×20' if kind == 'big' else '3×3'}"):
            continue
        sens, scen = pixels(kind, device)
        ch = wl.index(lam)
        t0 = time.perf_counter()
        y = simulated({"diffraction": {"wavelength_nm": wl}, **extra}, device, sens, scen, ch)
        t_sim = time.perf_counter() - t0
        t0 = time.perf_counter()
        coarse = reference(extra, device, sens, scen, lam, steps[0], args.quick)
        fine = reference(extra, device, sens, scen, lam, steps[1], args.quick)
        t_ref = time.perf_counter() - t0
        if extra:
            without = simulated({"diffraction": {"wavelength_nm": wl}, **base}, device, sens,
                                scen, ch)
            size = f"{rel_rms(without, fine):.1e}"
        else:
            size = f"geometric: {rel_rms(simulated({}, device, sens, scen, ch), fine):.1e}"
        print(f"| {name} | {'16×20' if kind == 'big' else '3×3'} | {rel_rms(y, fine):.1e} | "
              f"{rel_rms(coarse, fine):.1e} | {size} | {t_sim:.1f} | {t_ref:.1f} |", flush=True)
    if args.subsampling:
        prof = tiny_profile({}, **BIG)
        ref = crossing_grid_reference_kernel(prof, 530.0, 0.05, 3, BIG_SENSOR, BIG_SCENE)
        print("\n| plain sub-sampling (Gauss-Legendre n² per pixel) | vs converged reference |")
        print("|---|---|")
        for n in (8, 16, 24, 32, 48):
            sub = subsampled_reference_kernel(prof, 530.0, n, n, BIG_SENSOR, BIG_SCENE)
            print(f"| n = {n} | {rel_rms(sub, ref):.1e} |", flush=True)


if __name__ == "__main__":
    main()
