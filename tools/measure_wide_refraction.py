"""The wide device's blocked refracted kernel against a brute force (issue 34 item 1).

Device: issue 34's wide field, 128×160 sensor pixels of 40 µm, 50×64 scene pixels of 126 µm,
a 127-cell 60 µm mask, z = 4.8 mm, d = 1.0 mm, refraction n = 1.41 (air angles to 77°).
Builds the kernel the simulator builds (``get_kernel``: blocked, coupling bins) and the same
with the coupling frozen (``COUPLING_BIN_UM`` = 1e9), reporting each build's time and peak
RSS, then the exact-Snell brute force (:func:`~thintact_sdk.simulation.reference.reference_kernel`)
at two sample counts for six sensor pixels (the corners, the centre, (10, 80)) × eight scene
pixels (the corners, then four inside). Prints a Markdown table of the relative RMS per scene
pixel over those sensor pixels, with the brute force's own change between its two sample
counts. Takes about 20 minutes on one core; the finest reference needs about 19 GiB.

    python tools/measure_wide_refraction.py [--samples 56 72] [--skip-frozen]
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from thintact_sdk.formats.profiles import profile_from_dict  # noqa: E402
from thintact_sdk.host.machine import machine_summary  # noqa: E402
from thintact_sdk.simulation import refracted_blocked as rb  # noqa: E402
from thintact_sdk.simulation.effects import resolve_physics  # noqa: E402
from thintact_sdk.simulation.params import kernel_params  # noqa: E402
from thintact_sdk.simulation.reference import reference_kernel  # noqa: E402
from thintact_sdk.simulation.simulator import clear_kernel_cache, get_kernel  # noqa: E402

R, S, N, M = 128, 160, 50, 64
WIDE = {
    "format": "thintact-profile/1", "name": "wide-refraction",
    "sensor": {"rows": R, "cols": S, "pixel_pitch_um": 40.0},
    "scene": {"rows": N, "cols": M, "pixel_pitch_um": 126.0},
    "mask": {"feature_um": 60.0, "phi": [1 if i % 3 else -1 for i in range(127)]},
    "geometry": {"scene_to_mask_mm": 4.8, "mask_to_sensor_mm": 1.0},
    "noise": {"black_level_dn": 64.0, "read_noise_dn": 2.0, "electrons_per_dn": 4.0, "saturation_dn": 4095.0},
    "physics": {"refraction": {"n_scene_side": 1.41}},
}
SENSOR = np.array([0, S - 1, (R - 1) * S, R * S - 1, (R // 2) * S + S // 2, 10 * S + 80])
SCENE = [(0, 0), (0, M - 1), (N - 1, 0), (N - 1, M - 1), (25, 32), (5, 32), (25, 2), (40, 55)]


def _peak_gib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def _rel(a: np.ndarray, ref: np.ndarray) -> list[str]:
    v = np.sqrt(((a - ref) ** 2).mean(axis=0) / (ref**2).mean(axis=0))
    return [f"{x:.1e}" for x in v]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, nargs=2, default=[56, 72],
                    help="brute-force samples per pixel axis: a coarser and the reference count")
    ap.add_argument("--skip-frozen", action="store_true", help="do not build the frozen-coupling kernel")
    args = ap.parse_args()
    prof = profile_from_dict(WIDE)
    kp = kernel_params(prof, resolve_physics(prof.physics))
    scene = np.array([n * M + m for n, m in SCENE])
    print(f"host: {machine_summary()}", file=sys.stderr)
    rows: list[tuple[str, np.ndarray]] = []
    t0 = time.perf_counter()
    kern = get_kernel(kp, lambda d, t: print(f"  {d}/{t} steps", file=sys.stderr) if d % 100 == 0 else None)
    print(f"bins: build {time.perf_counter() - t0:.1f} s, peak RSS {_peak_gib():.2f} GiB, "
          f"info {kern.info}", file=sys.stderr)
    rows.append(("**bins (default)**", kern.G[np.ix_(SENSOR, scene)].astype(float)))
    del kern
    clear_kernel_cache()
    if not args.skip_frozen:
        old = rb.COUPLING_BIN_UM
        rb.COUPLING_BIN_UM = 1e9
        try:
            t0 = time.perf_counter()
            frozen = rb.build_blocked_refracted_kernel(kp)
        finally:
            rb.COUPLING_BIN_UM = old
        print(f"frozen: build {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        rows.insert(0, ("coupling frozen", frozen.G[np.ix_(SENSOR, scene)].astype(float)))
        del frozen
    refs = []
    for n in args.samples:
        t0 = time.perf_counter()
        refs.append(reference_kernel(prof, n, n, SENSOR, scene))
        print(f"brute force {n}²: {time.perf_counter() - t0:.1f} s, peak RSS {_peak_gib():.2f} GiB",
              file=sys.stderr)
    coarse, ref = refs
    print("| scene pixel (row, col) | " + " | ".join(f"({n}, {m})" for n, m in SCENE) + " |")
    print("|---" * (len(SCENE) + 1) + "|")
    for name, g in rows:
        print(f"| {name} | " + " | ".join(_rel(g, ref)) + " |")
    a, b = args.samples
    print(f"| brute force {a}² against {b}² | " + " | ".join(_rel(coarse, ref)) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
