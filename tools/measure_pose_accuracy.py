"""Accuracy of ``thintact calibrate-pose`` on simulated flat fields with known pose (issue 12).

The truth is the exact simulator (CONTRACTS §4, its rotated-mask path for the residual turn)
of a 128×160 device with a random φ and a different φ_rows (tests/calibration's
``small_profile``), the mask mounted in one of the 8 orientations, shifted by (−7.3, 4.1) um,
turned by the residual angle, at z = 4.9 mm instead of the nominal 4.8 mm. Each case is
estimated from one flat field, noiseless and with the profile's noise (Poisson electrons,
read noise, rounding) with the flat field peaking at 2000 DN. Prints a Markdown table.

    python tools/measure_pose_accuracy.py [--quick]
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
from thintact_sdk.imaging.mask_orientation import ORIENTATIONS, Orientation  # noqa: E402
from thintact_sdk.imaging.simulator import Simulator  # noqa: E402
from thintact_sdk.profile import Profile  # noqa: E402

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


if __name__ == "__main__":
    main()
