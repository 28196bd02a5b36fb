# ruff: noqa: I001  (thintact_sdk is imported before numpy on purpose)
"""Simulator benchmark: speed at the paper's full size, accuracy against brute force and the
golden baseline, and the diagnosis workload (128×160 device, 24 frames).

Usage: ``.venv/bin/python tools/bench_simulator.py [--skip-paper] [--golden DIR]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import thintact_sdk  # noqa: F401  (first: tunes OpenBLAS before numpy loads)
import numpy as np

from thintact_sdk.simulation.reference import reference_forward
from thintact_sdk.simulation.simulator import Simulator, clear_kernel_cache
from thintact_sdk.host.machine import machine_summary
from thintact_sdk.formats.profiles import Profile, load_profile, profile_from_dict, read_profile_file


def _rel_rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2)))


def _small(rows: int, cols: int, n_rows: int, n_cols: int, pitch: float, spitch: float,
           feature: float, k: int, z: float, d: float) -> Profile:
    rng = np.random.default_rng(0)
    return profile_from_dict({
        "format": "thintact-profile/1", "name": "bench-small",
        "sensor": {"rows": rows, "cols": cols, "pixel_pitch_um": pitch},
        "scene": {"rows": n_rows, "cols": n_cols, "pixel_pitch_um": spitch},
        "mask": {"feature_um": feature, "phi": [int(v) for v in rng.choice([-1, 1], k)]},
        "geometry": {"scene_to_mask_mm": z, "mask_to_sensor_mm": d},
        "noise": {"black_level_dn": 64, "read_noise_dn": 2, "electrons_per_dn": 4,
                  "saturation_dn": 4095},
    })


def _timed(fn, repeat: int = 1) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def bench_paper() -> None:
    prof = load_profile("thintact-paper")
    x = np.random.default_rng(0).random((1, prof.scene.rows, prof.scene.cols, 3))
    clear_kernel_cache()
    sim = Simulator(prof)
    t_build, _ = _timed(lambda: sim.kernel)
    info = sim.info()
    t64, _ = _timed(lambda: sim.forward_batch(x), 3)
    sim32 = Simulator(prof, precision="float32")
    t32, y32 = _timed(lambda: sim32.forward_batch(x), 3)
    y64 = sim.forward_batch(x)
    mem = sum(t.P.nbytes + t.Q.nbytes for t in sim.kernel.terms[0]) / 2**20
    print(f"paper size (sensor 1024×1280, scene 400×512, K={prof.mask.K}):")
    print(f"  kernel build {t_build:.1f} s; radiometric rank {info['rank']:.0f} "
          f"(max rel. error {info['radiometric_rel_error']:.1e}); {info['terms']:.0f} separable "
          f"terms per channel after compression ({mem:.0f} MiB, shared by R, G, B)")
    print(f"  forward per RGB frame: {t64:.2f} s float64, {t32:.2f} s float32 "
          f"(float32 vs float64 rel. RMS {_rel_rms(np.asarray(y32), y64):.1e})")


def bench_accuracy() -> None:
    cases = {
        "paper-like pitches, 8×10 sensor (10 um), 4×5 scene (31.5 um), z=4.8, d=1.0":
            _small(8, 10, 4, 5, 10.0, 31.5, 20.0, 32, 4.8, 1.0),
        "wide angles, 6×8 sensor (100 um), 4×5 scene (300 um), z=2.0, d=0.5":
            _small(6, 8, 4, 5, 100.0, 300.0, 80.0, 16, 2.0, 0.5),
    }
    print("fast separable path vs brute-force 4-D midpoint quadrature (n² points per pixel):")
    for name, prof in cases.items():
        x = np.random.default_rng(1).random((prof.scene.rows, prof.scene.cols, 3))
        y = Simulator(prof).forward(x)
        errs = []
        for n in (8, 16, 24):
            errs.append(f"n={n}: {_rel_rms(y, reference_forward(prof, x, n, n)):.1e}")
        print(f"  {name}: rel. RMS " + ", ".join(errs))


def bench_golden(golden: Path) -> None:
    import json

    print("golden baseline (rel. RMS per frame after one gain per channel):")
    for dev in ("mini", "wide"):
        d = golden / dev
        if not d.is_dir():
            print(f"  {dev}: not found at {d}")
            continue
        prof = read_profile_file(d / "profile.json")
        scenes, gold = np.load(d / "scenes.npy"), np.load(d / "irradiance.npy")
        labels = json.loads((d / "labels.json").read_text())
        y = Simulator(prof).forward_batch(scenes)
        g = np.array([y[..., c].ravel() @ gold[..., c].ravel() / (y[..., c].ravel() @ y[..., c].ravel())
                      for c in range(3)])
        errs = ", ".join(f"{lab} {_rel_rms(y[f] * g, gold[f]):.1e}" for f, lab in enumerate(labels))
        print(f"  {dev}: {errs}")


def bench_diagnosis() -> None:
    prof = load_profile("virtual-mini")
    x = np.random.default_rng(2).random((24, prof.scene.rows, prof.scene.cols, 3))
    clear_kernel_cache()
    t_sep, _ = _timed(lambda: Simulator(prof).forward_batch(x))
    t_eval, _ = _timed(lambda: Simulator(prof.with_physics({"sensor_gamma": {"gamma": 0.9}}))
                       .predict_dn(x, 2e4), 3)
    t_leak, _ = _timed(lambda: Simulator(prof.with_physics({"mask_leakage": {"transmittance": 0.05}}))
                       .forward_batch(x))
    t_rot, _ = _timed(lambda: Simulator(prof.with_physics({"mask_misalignment": {"angle_deg": 0.3}}))
                      .forward_batch(x))
    t_ref, _ = _timed(lambda: Simulator(prof.with_physics({"refraction": {"n_scene_side": 1.4}}))
                      .forward_batch(x))
    t_dif, _ = _timed(lambda: Simulator(prof.with_physics({"diffraction": {}})).forward_batch(x))
    print("diagnosis workload (128×160 sensor, 50×64 scene, 24 RGB frames):")
    print(f"  separable kernel build + 24 frames {t_sep:.2f} s; post-kernel effect change "
          f"(cached kernel) {t_eval:.2f} s; new separable kernel (leakage) {t_leak:.2f} s")
    print(f"  diffraction (3 wavelengths) {t_dif:.2f} s; direct path: rotated mask {t_rot:.2f} s, "
          f"refraction {t_ref:.2f} s (build + 24 frames)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--skip-paper", action="store_true", help="skip the full-size timing")
    ap.add_argument("--golden", type=Path,
                    default=Path(__file__).resolve().parents[1].parent / "shared/golden/baseline")
    args = ap.parse_args()
    print(machine_summary())
    if not args.skip_paper:
        bench_paper()
    bench_accuracy()
    bench_golden(args.golden)
    bench_diagnosis()


if __name__ == "__main__":
    main()
