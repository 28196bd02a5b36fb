"""Peak memory and time of the health step (``assess``) on a synthetic recording.

Usage::

    python tools/measure_health_memory.py --out DIR --sensor 256 320 --scene 96 128
    python tools/measure_health_memory.py --out DIR --sensor 1024 1280 --scene 40 51 --random

Without ``--random`` the recording is independent-style (the exact simulator with the true
physics of ``tests/calibration/independent_device.py``, one capture per scene) and the matrices
are solved from it; with ``--random`` the matrices are random separable ones (smooth open
terms, ±30 % coding) and the frames their noisy prediction, which is what a paper-size sensor
allows in minutes (the ghost search then reads nonsense echo strengths: the matrices are not
the profile's design). ``assess`` then runs in a fresh process, so its peak RSS is its own.
"""

from __future__ import annotations

import argparse
import pickle
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "calibration"))


def _make(out: Path, rows: int, cols: int, n: int, m: int, random: bool) -> None:
    from independent_device import small_profile, write_recording
    from sim_cli_device import calibration_scenes

    from thintact_sdk.calibration.collect import collect_slits
    from thintact_sdk.calibration.pipeline import CalibrationOptions, solve_matrices
    from thintact_sdk.formats.recording import Recording, RecordingWriter
    from thintact_sdk.host.blas import blas_threads
    from thintact_sdk.reconstruction.t2s import SystemMatrices

    profile = small_profile(("R", "G", "B"), rows=rows, cols=cols, scene=(n, m), k=max(96, 96 * cols // 80))
    t = time.time()
    if not random:
        rec = write_recording(out / "rec", profile, seed=0)
        collection = collect_slits(rec)
        sm, _ = solve_matrices(collection, CalibrationOptions(), profile)
    else:
        rng = np.random.default_rng(0)

        def smooth(a: int, b: int) -> np.ndarray:
            u, v = np.linspace(-1, 1, a)[:, None], np.linspace(-1, 1, b)[None, :]
            return np.asarray(np.exp(-((u - v) ** 2) / 0.05))

        po, qo = smooth(rows, n), smooth(cols, m)
        pc, qc = po * rng.choice([-0.3, 0.3], (rows, n)), qo * rng.choice([-0.3, 0.3], (cols, m))
        nz = profile.noise
        sm = SystemMatrices(np.stack([po] * 3), np.stack([qo] * 3), np.stack([pc] * 3), np.stack([qc] * 3))
        g = np.sqrt(0.7 * (nz.saturation_dn - nz.black_level_dn) / float(sm.forward(np.ones((n, m, 3))).max()))
        sm = SystemMatrices(sm.Po * g, sm.Qo * g, sm.Pc * g, sm.Qc * g)
        w = RecordingWriter(out / "rec", profile)
        scenes = calibration_scenes(n, m)[: 2 + n + m]  # dark, white and every slit
        with blas_threads(1):
            for label, x in scenes:
                s = sm.forward(x.astype(np.float64))
                e = rng.poisson(np.clip(s, 0, None) * nz.electrons_per_dn) / nz.electrons_per_dn
                dn = np.rint(e + rng.normal(0.0, nz.read_noise_dn, s.shape) + nz.black_level_dn)
                w.add(np.clip(dn, 0, nz.saturation_dn).astype(np.uint16), x, label=label)
        collection = collect_slits(Recording(out / "rec"))
    print(f"recording, collection and matrices: {time.time() - t:.1f} s", flush=True)
    with open(out / "collection_matrices.pkl", "wb") as f:
        pickle.dump((collection, sm), f)


def _assess(out: Path) -> None:
    from thintact_sdk.calibration.health import assess
    from thintact_sdk.formats.recording import Recording

    rec = Recording(out / "rec")
    with open(out / "collection_matrices.pkl", "rb") as f:
        collection, sm = pickle.load(f)  # noqa: S301 (our own file, written just before)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t = time.time()
    report = assess(rec, collection, sm, 1)
    seconds = time.time() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"assess: {len(report.slit_chi2)} slits, {seconds:.1f} s, peak RSS {peak:.0f} MiB "
          f"({before:.0f} MiB before it); noise {report.noise.to_json()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--sensor", type=int, nargs=2, default=(256, 320))
    ap.add_argument("--scene", type=int, nargs=2, default=(96, 128))
    ap.add_argument("--random", action="store_true")
    ap.add_argument("--assess-only", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.assess_only:
        _assess(args.out)
        return
    args.out.mkdir(parents=True, exist_ok=True)
    if not (args.out / "collection_matrices.pkl").exists():
        (rows, cols), (n, m) = args.sensor, args.scene
        _make(args.out, rows, cols, n, m, args.random)
    subprocess.run([sys.executable, __file__, "--out", str(args.out), "--assess-only"], check=True)


if __name__ == "__main__":
    main()
