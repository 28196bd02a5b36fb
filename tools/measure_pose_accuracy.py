"""Accuracy of ``thintact calibrate-pose`` on simulated flat fields with known pose (issue 12).

The truth is the exact simulator (CONTRACTS §4, its rotated-mask path for the residual turn)
of a 128×160 device with a random φ and a different φ_rows (tests/calibration's
``small_profile``), the mask mounted in one of the 8 orientations, shifted by (−7.3, 4.1) um,
turned by the residual angle, at z = 4.9 mm instead of the nominal 4.8 mm. Each case is
estimated from one flat field, noiseless and with the profile's noise (Poisson electrons,
read noise, rounding) with the flat field peaking at 2000 DN. Prints a Markdown table.

    python tools/measure_pose_accuracy.py [--quick]
    python tools/measure_pose_accuracy.py --concealed   # the concealed-pose set (issue 32)
    python tools/measure_pose_accuracy.py --large [DIR] # a 2160×3840 frame: time and memory (DIR: write it)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "calibration"))

from independent_device import mounted_profile, small_profile  # noqa: E402

from thintact_sdk.calibration.pose import estimate_pose  # noqa: E402
from thintact_sdk.formats.profiles import Profile  # noqa: E402
from thintact_sdk.reconstruction.mask_orientation import ORIENTATIONS, Orientation  # noqa: E402
from thintact_sdk.simulation.simulator import Simulator  # noqa: E402

DX, DY, Z = -7.3, 4.1, 4.9
WHITE_DN = 2000.0


def mounted(nominal: Profile, orientation: Orientation, angle_deg: float) -> Profile:
    return mounted_profile(nominal, orientation, angle_deg, DX, DY, Z)


def noisy(flat: np.ndarray, profile: Profile, rng: np.random.Generator) -> np.ndarray:
    e = profile.noise.electrons_per_dn
    sig = rng.poisson(np.clip(flat, 0, None) * e) / e + rng.normal(0, profile.noise.read_noise_dn, flat.shape)
    return np.round(sig)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="skip the 1° and 3° cases (slow to simulate)")
    args = ap.parse_args()
    nominal = small_profile(("G",), rows=128, cols=160)
    n, m = nominal.scene.rows, nominal.scene.cols
    by_name = {o.name: o for o in ORIENTATIONS}
    cases = [("as designed", a) for a in (0.0, 0.02, 0.05, 0.3)]
    if not args.quick:
        cases += [("as designed", 1.0), ("as designed", -3.0)]
    cases += [("turned by 180°", 0.0), ("turned by 90°", 0.0), ("mirrored left-right", 0.0),
              ("turned by 180°", 0.05), ("turned by 90°", -0.3), ("mirrored left-right", -0.05),
              ("mirrored about the diagonal (x ↔ y)", 0.02)]
    rng = np.random.default_rng(0)
    print("| mounting | true angle ° | noise | orientation found | angle error ° | dx error um | "
          "dy error um | z error mm | time s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, angle in cases:
        truth = mounted(nominal, by_name[name], angle)
        lin = Simulator(truth).linear_batch(np.ones((1, n, m, 1)))[0]
        flat = lin / float(lin.max()) * WHITE_DN
        for label, y in (("none", flat), ("yes", noisy(flat, nominal, rng))):
            t0 = time.perf_counter()
            est = estimate_pose(y, nominal)
            dt = time.perf_counter() - t0
            same = np.array_equal(np.stack(est.orientation.apply(np.asarray(nominal.mask.phi),
                                                                  np.asarray(nominal.mask.rows_vector))),
                                  np.stack([truth.mask.phi, truth.mask.rows_vector]))
            print(f"| {name} | {angle:+.2f} | {label} | {est.orientation.name if same else 'WRONG'} | "
                  f"{est.angle_deg - angle:+.4f} | {est.dx_um - DX:+.3f} | {est.dy_um - DY:+.3f} | "
                  f"{est.scene_to_mask_mm - Z:+.4f} | {dt:.1f} |", flush=True)


def large_frame(rows: int = 2160, cols: int = 3840) -> None:
    """Time and peak memory of the pose on a full-size frame (issue 32): a 200-cell mask of
    40 um cells, 1 um pixels, the flat field drawn from the flat-field model itself (separable
    with a 0.5° turn, the mask turned by 180°) with the profile's noise; the pose fits z."""
    import resource

    from thintact_sdk.calibration.pose import _FlatModel

    rng = np.random.default_rng(4)
    d = small_profile(("G",), rows=rows, cols=cols, k=200, scene=(30, 50)).contract_dict()
    d["sensor"]["pixel_pitch_um"] = 1.0
    d["scene"]["pixel_pitch_um"] = 100.0
    d["mask"]["feature_um"] = 40.0
    d["mask"]["phi"] = rng.choice([-1, 1], 200).tolist()
    d["mask"]["phi_rows"] = rng.choice([-1, 1], 200).tolist()
    nominal = Profile.model_validate(d)
    o = Orientation.turned(2)
    px, py = o.apply(np.asarray(nominal.mask.phi, float), np.asarray(nominal.mask.rows_vector, float))
    halves = _FlatModel(nominal, px, py).halves(0.5, 120.0, -80.0, 5.0, 1.0)
    flat = halves.sum(axis=0)
    flat = flat / float(flat.max()) * WHITE_DN
    flat = noisy(flat, nominal, rng)
    del halves
    if len(sys.argv) > 2:  # --large DIR: write the frame and the profile for a CLI run instead
        from thintact_sdk.formats.profiles import write_profile

        out = Path(sys.argv[2])
        out.mkdir(parents=True, exist_ok=True)
        np.save(out / "flat.npy", (flat + nominal.noise.black_level_dn).astype(np.uint16))
        write_profile(nominal, out / "nominal.json")
        print(f"written {out / 'flat.npy'} and {out / 'nominal.json'}")
        return
    t0 = time.perf_counter()
    est = estimate_pose(flat, nominal, unknown="z", progress=lambda m: print(f"  [{time.perf_counter() - t0:6.1f} s] {m}"))
    dt = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{rows}×{cols}: {dt:.1f} s, peak RSS {peak:.0f} MiB (whole process, frame generation included); "
          f"found {est.orientation.name} (truth {o.name}), angle {est.angle_deg:+.3f}° (0.5), "
          f"dx {est.dx_um:+.1f} (120), dy {est.dy_um:+.1f} (−80) um, z {est.scene_to_mask_mm:.4f} ± "
          f"{est.scale_sigma:.4f} mm (5.0), confident {est.confident}, margin {est.margin_sigma:.1f}, "
          f"runner-up {est.runner_up.orientation.name if est.runner_up else None}")


def concealed(n: int, seed: int) -> None:
    """The concealed-pose set of tests/calibration/concealed_pose.py as a Markdown table."""
    from concealed_pose import flat_field, judge, nominal_profile, random_cases, truth_profile

    nominal = nominal_profile()
    print("| case | found | runner-up | margin σ | floor σ (x, y) | pitch um (true) | verdict | time s |")
    print("|---|---|---|---|---|---|---|---|")
    counts: dict[str, int] = {}
    for i, case in enumerate(random_cases(n, seed)):
        truth = truth_profile(nominal, case)
        flat = flat_field(truth, np.random.default_rng(i))
        t0 = time.perf_counter()
        est = estimate_pose(flat, nominal, unknown="pitch", bounds=(9.0, 11.0))
        dt = time.perf_counter() - t0
        verdict = judge(est, nominal, truth, case)
        counts[verdict] = counts.get(verdict, 0) + 1
        h = est.hypotheses[0]
        print(f"| {case.label()} | {est.orientation.name} {est.angle_deg:+.3f}° ({est.dx_um:+.1f}, "
              f"{est.dy_um:+.1f}) | {est.runner_up.orientation.name if est.runner_up else '-'} | "
              f"{est.margin_sigma:.1f} | {h.sigma_x:.1f}, {h.sigma_y:.1f} | {est.pixel_pitch_um:.4f} ± "
              f"{est.scale_sigma:.4f} ({truth.sensor.pixel_pitch_um:.4f}) | {verdict} | {dt:.1f} |", flush=True)
    print(f"\n{counts}")


if __name__ == "__main__":
    if "--large" in sys.argv:
        large_frame()
    elif "--concealed" in sys.argv:
        concealed(16, 32)
    else:
        main()
