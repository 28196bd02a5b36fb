"""Closing measurements of issue 12 on the issue's independent-style device.

The device of the issue: 128 × 160 sensor at 10 µm, 50 × 64 scene at 31.5 µm, 20 µm cells,
K = 128 random φ (and a different φ_rows), z 4.8 mm, d 1.0 mm in the profile; the recording
is made by the exact simulator with the true physics of ``tests/calibration/independent_device.py``
(z 4.86, d 0.99 mm, mask shifted (3, −2) µm and turned 0.03°), the contract's noise, one capture
per scene: dark, white, every row and column slit and six validation scenes. A second recording
of the same unit holds 23 scenes the calibration never saw (the test scenes).

Measured, for the healthy unit: ``thintact calibrate --from-recording`` (verdict, the τ each
criterion chose, τ per channel kept or not, the scene prior chosen), the mean PSNR of default
``thintact reconstruct`` on the test scenes, the same decoder with the best τ in hindsight (with
the bundle's scene prior, and with plain Tikhonov), and the paper's Alg. 1-3
(``--method paper``) + exact ``t2s-closed-form`` with its best τ in hindsight. Then the same
unit with a dust speck, with a dim column and with a ghost, each calibrated on its own: the
exit status and the defects named.

Usage (about 5 min on an idle 2-core host, 15 under load)::

    python tools/measure_issue12.py --out /tmp/issue12 --filter-steps 10 --all-decoders \\
        [--cases healthy,dust,dim,ghost,ghost8,ghost_separable]

Writes ``DIR/summary.json`` and prints each case's figures (JSON) as it finishes.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "calibration"))

from independent_device import (  # noqa: E402
    TRUE_PHYSICS,
    DimColumn,
    Dust,
    Ghost,
    best_in_hindsight,
    mean_psnr,
    small_profile,
    write_recording,
)

from thintact_sdk.apps.cli.main import main  # noqa: E402
from thintact_sdk.calibration.collect import collect_slits, signal_of  # noqa: E402
from thintact_sdk.calibration.pipeline import CalibrationOptions, solve_matrices  # noqa: E402
from thintact_sdk.calibration.validation import make_decoder  # noqa: E402
from thintact_sdk.formats.profiles import Profile  # noqa: E402
from thintact_sdk.formats.recording import Recording, RecordingWriter  # noqa: E402
from thintact_sdk.reconstruction.bundle import CalibrationBundle  # noqa: E402
from thintact_sdk.simulation.noise import signal_to_dn  # noqa: E402
from thintact_sdk.simulation.scenes import checker, gelsight, random_pixels, usaf, white  # noqa: E402
from thintact_sdk.simulation.simulator import Simulator  # noqa: E402

DEFECTS: dict[str, list[Dust | DimColumn | Ghost]] = {
    "dust": [Dust(row=40, col=100)],
    "dim": [DimColumn(col=70)],
    "ghost": [Ghost(6, -9, 0.05)],
    "ghost8": [Ghost(6, -9, 0.08)],
    "ghost_separable": [Ghost(0, 11, 0.05)],
}
"""Each defective unit's defect (sensor pixels; ghosts at 5 % or 8 % of the image, diagonal or along
an axis; ``--cases`` picks them)."""


def issue_profile() -> Profile:
    """The issue's device as its profile describes it (nominal physics)."""
    return small_profile(("R", "G", "B"), rows=128, cols=160, scene=(50, 64), k=128)


def test_scenes(n: int, m: int) -> list[tuple[str, np.ndarray]]:
    """23 scenes the calibration never saw: five other presses, the no-contact gel, white,
    USAF, three checkers, ten smooth random fields, two random-pixel scenes."""
    from scipy.ndimage import gaussian_filter

    out = [(f"test_gelsight_{i}", gelsight(n, m, i)) for i in range(3, 8)]
    out += [("test_gel_no_contact", gelsight(n, m, -1)), ("test_white", white(n, m)), ("test_usaf", usaf(n, m))]
    out += [(f"test_checker_{p}", checker(n, m, p)) for p in (4, 6, 12)]
    rng = np.random.default_rng(7)
    for i in range(10):
        sigma = 1.5 + 0.5 * i
        field = gaussian_filter(rng.random((n, m, 3)), (sigma, sigma, 0))
        out.append((f"test_field_{i}", (field - field.min()) / np.ptp(field)))
    out += [(f"test_random_{i}", random_pixels(n, m, 100 + i)) for i in range(2)]
    return [(label, np.asarray(x, np.float32)) for label, x in out]


def write_test_recording(root: Path, profile: Profile, seed: int = 99) -> Recording:
    """The same unit (true physics, same signal level as ``write_recording``), test scenes."""
    sim = Simulator(profile.with_physics(TRUE_PHYSICS))
    nz = profile.noise
    n, m = profile.scene.rows, profile.scene.cols
    gain = 0.7 * (nz.saturation_dn - nz.black_level_dn) / float(np.max(sim.linear_batch(np.ones((1, n, m, 3)))))
    rng = np.random.default_rng(seed)
    w = RecordingWriter(root, profile)
    w.add(signal_to_dn(np.zeros((profile.sensor.rows, profile.sensor.cols, 3)), nz, rng).astype(np.uint16),
          np.zeros((n, m, 3), np.float32), label="dark")
    for label, x in test_scenes(n, m):
        w.add(signal_to_dn(sim.predict_signal_dn(x, gain), nz, rng).astype(np.uint16), x, label=label)
    return Recording(root)


def calibrate(rec: Path, cal: Path, filter_steps: int | None) -> tuple[int, float, dict[str, Any]]:
    """``thintact calibrate --from-recording``: exit status, wall time (s), calibration.json."""
    args = ["calibrate", "--from-recording", str(rec), "--out", str(cal), "--no-progress", "--force"]
    if filter_steps is not None:
        args += ["--filter-steps", str(filter_steps)]
    t0 = time.perf_counter()
    rc = main(args)
    return rc, time.perf_counter() - t0, json.loads((cal / "calibration.json").read_text())


def measure_healthy(root: Path, filter_steps: int | None, *, reuse: bool = False, exact_open: bool = False,
                    all_decoders: bool = False) -> dict[str, Any]:
    """The healthy unit's figures (``reuse``: keep a calibration and test recording already in
    ``root``; ``exact_open``: the reference keeps every open mode, slow at this size;
    ``all_decoders``: best hindsight τ of every compared decoder, not only the recommended)."""
    profile = issue_profile()
    if reuse and (root / "cal" / "calibration.json").exists() and (root / "test").exists():
        meta = json.loads((root / "cal" / "calibration.json").read_text())
        rc, wall = (0 if meta["metrics"]["passed"] else 1), float("nan")
        test = Recording(root / "test")
    else:
        write_recording(root / "rec", profile, seed=0)
        rc, wall, meta = calibrate(root / "rec", root / "cal", filter_steps)
        test = write_test_recording(root / "test", profile)
    m = meta["metrics"]
    sel = m["tau_selection"]
    shutil.rmtree(root / "default", ignore_errors=True)  # reconstruct refuses a non-empty --out
    assert main(["reconstruct", str(root / "test"), "--calibration", str(root / "cal"),
                 "--out", str(root / "default"), "--no-progress"]) == 0
    default = mean_psnr(root / "default", test)
    bundle = CalibrationBundle.load(root / "cal")
    dark = np.asarray(test.measurement(0), np.float64)
    frames = [(signal_of(test, i, dark, None)[0].astype(np.float32), np.asarray(test.scene(i)))
              for i in range(1, len(test))]
    print("best tau in hindsight on the test scenes ...", file=sys.stderr, flush=True)
    hindsight = {name: best_in_hindsight(make_decoder(profile, bundle, name), frames)
                 for name in (sel["decoder_taus"] if all_decoders else [meta["decoder"]])}
    # the same decoders with plain Tikhonov (a bundle's scene prior left out): one τ, best in hindsight
    plain = {name: best_in_hindsight(make_decoder(profile, bundle, name, prior=None), frames)
             for name in (meta.get("scene_prior") or {}) if name in hindsight}
    print("Alg. 1-3 (--method paper) + t2s-closed-form ...", file=sys.stderr, flush=True)
    paper_sm, _ = solve_matrices(collect_slits(Recording(root / "rec")), CalibrationOptions(method="paper"), profile)
    paper = CalibrationBundle.create(profile, paper_sm, None, tau=1.0, source="recording")
    # t2s-closed-form truncates Po, Qo in whichever gauge drops less (exact for a low-rank open
    # term); every open mode (exact_open) makes a (2·50·64)² system per τ and channel here
    exact = {"open_rtol": 0.0, "max_open_rank": 10**6} if exact_open else {}
    reference = best_in_hindsight(make_decoder(profile, paper, "t2s-closed-form", **exact), frames)
    return {
        "exit_status": rc, "passed": m["passed"], "failures": m["verdict"]["failures"],
        "defects": m["health"]["defects"], "calibration_wall_s": round(wall, 1),
        "decoder": meta["decoder"], "criterion": sel["criterion"], "decoder_taus": sel["decoder_taus"],
        "criteria": {c["criterion"]: {"tau": c["tau"], "note": c["note"]} for c in sel["curves"]},
        "held_out_mean_psnr_db": sel["held_out_mean_psnr_db"], "channel_tau": sel["channel_tau"],
        "per_channel_check": {k: {kk: v[kk] for kk in v if kk != "leave_one_out_tau"}
                              for k, v in sel["per_channel_check"].items()},
        "shortfall_db": [[s.get("scene"), s.get("shortfall_db")] for s in m["verdict"]["scenes"]],
        "test_scenes": len(frames),
        "default_reconstruct_db": round(default, 3),
        "scene_prior": sel.get("scene_prior", {}), "scene_prior_candidates": sel.get("scene_prior_candidates", {}),
        "hindsight_db": {k: [round(v[0], 3), float(f"{v[1]:.3g}")] for k, v in hindsight.items()},
        "hindsight_plain_tikhonov_db": {k: [round(v[0], 3), float(f"{v[1]:.3g}")] for k, v in plain.items()},
        "paper_alg13_t2s_hindsight_db": [round(reference[0], 3), float(f"{reference[1]:.3g}")],
        "paper_reference_open_modes": "all" if exact_open else "t2s-closed-form default (gauge-aware rank 8)",
    }


def measure_defect(root: Path, name: str) -> dict[str, Any]:
    write_recording(root / "rec", issue_profile(), seed=0, defects=DEFECTS[name])
    rc, wall, meta = calibrate(root / "rec", root / "cal", 0)
    m = meta["metrics"]
    return {"exit_status": rc, "passed": m["passed"], "injected": repr(DEFECTS[name]),
            "defects": m["health"]["defects"],
            "failures": [f for f in m["verdict"]["failures"] if f.get("what") != "psnr"],
            "calibration_wall_s": round(wall, 1)}


def main_cli(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--cases", default=",".join(["healthy", *DEFECTS]))
    ap.add_argument("--filter-steps", type=int, default=None,
                    help="healthy unit's filter training steps (default: calibrate's default)")
    ap.add_argument("--reuse", action="store_true", help="reuse the healthy calibration and test recording in --out")
    ap.add_argument("--exact-open", action="store_true",
                    help="reference decodes with every open mode (hours at this size on 2 cores)")
    ap.add_argument("--all-decoders", action="store_true", help="best hindsight τ of every compared decoder")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    summary_path = args.out / "summary.json"
    summary: dict[str, Any] = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    for case in args.cases.split(","):
        t0 = time.perf_counter()
        if case == "healthy":
            summary[case] = measure_healthy(args.out / case, args.filter_steps, reuse=args.reuse,
                                            exact_open=args.exact_open, all_decoders=args.all_decoders)
        else:
            summary[case] = measure_defect(args.out / case, case)
        summary[case]["case_wall_s"] = round(time.perf_counter() - t0, 1)
        summary_path.write_text(json.dumps(summary, indent=1, default=str))
        print(f"## {case}\n{json.dumps(summary[case], indent=1, default=str)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main_cli())
