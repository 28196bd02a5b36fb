"""Calibration under conditions it was not designed around: ``python -m thintact_sdk.calibration.stress_cases``.

Slit-scan recordings are simulated with the SDK's physics simulator (any CONTRACTS §5
effects), with an unknown black-level offset, per-frame exposure differences (recorded in
the frame metadata or not), averaged-frame noise, with or without a dark frame. Each is
calibrated with the paper's Algorithm 1 (``paper``) and the joint least-squares variant
(``lsq``, optionally with per-frame gains), and scored by the validation reconstructions
(PSNR/SSIM against the displayed scenes, non-iterative decoder).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.calibration.pipeline import CalibrationOptions, calibrate_recording
from thintact_sdk.calibration.plan import DEFAULT_VALIDATION, build_plan
from thintact_sdk.formats.profiles import Profile, load_profile
from thintact_sdk.formats.recording import Recording, RecordingWriter
from thintact_sdk.simulation.noise import signal_variance_dn

REFERENCE_EXPOSURE_US = 10_000.0


@dataclass
class Case:
    """One simulated recording condition."""

    name: str
    physics: dict[str, dict[str, Any]] = field(default_factory=dict)
    black_offset_dn: float = 0.0
    exposure_jitter: float = 0.0
    record_exposure: bool = True
    dark_frame: bool = True
    frames_averaged: int = 16


CASES = [
    Case("baseline"),
    Case("black +8 DN, dark frame", black_offset_dn=8.0),
    Case("black +8 DN, no dark frame", black_offset_dn=8.0, dark_frame=False),
    Case("exposure ±10 %, recorded", exposure_jitter=0.1),
    Case("exposure ±10 %, not recorded", exposure_jitter=0.1, record_exposure=False),
    Case("mask rotated 0.3°", physics={"mask_misalignment": {"angle_deg": 0.3, "dx_um": 5.0, "dy_um": -5.0}}),
    Case("sensor blur 8 um", physics={"sensor_blur": {"sigma_um": 8.0}}),
    Case("veiling glare 2 %", physics={"veiling_glare": {"fraction": 0.02}}),
    Case("few frames (K=2)", frames_averaged=2),
]


def simulate_recording(profile: Profile, root: Path, case: Case, seed: int = 0) -> Recording:
    """Record the wizard's pattern sequence through the simulator under ``case``.

    The recording's ``profile.json`` is the nominal profile (what the calibrating user
    believes); the simulation uses ``case.physics``, the black offset and the exposures.
    """
    from thintact_sdk.simulation.simulator import Simulator

    sim = Simulator(profile.with_physics(case.physics))
    gain = sim.reference_gain()
    nz = profile.noise
    rng = np.random.default_rng(seed)
    k = max(1, case.frames_averaged)
    writer = RecordingWriter(root, profile)
    steps = [s for s in build_plan(profile, DEFAULT_VALIDATION) if case.dark_frame or s.kind != "dark"]
    for s in steps:
        scene = s.make()
        factor = 1.0 + case.exposure_jitter * float(rng.uniform(-1.0, 1.0))
        signal = sim.predict_signal_dn(scene, gain) * factor
        var = signal_variance_dn(signal, nz, k)
        dn = signal + rng.standard_normal(signal.shape) * np.sqrt(var) + nz.black_level_dn + case.black_offset_dn
        dn = np.clip(dn, 0.0, nz.saturation_dn).astype(np.float32)
        extra: dict[str, Any] = {"frames": k}
        if case.record_exposure:
            extra["exposure_us"] = REFERENCE_EXPOSURE_US * factor
        writer.add(dn, scene, label=s.label, **extra)
    return Recording(root)


def run_case(profile: Profile, case: Case, methods: list[tuple[str, str]], work: Path) -> list[dict[str, Any]]:
    """Calibrate one simulated recording with every ``(method, frame_gains)``; returns rows."""
    rec = simulate_recording(profile, work / "rec", case)
    rows = []
    for method, gains in methods:
        t0 = time.perf_counter()
        out = calibrate_recording(
            rec, work / f"cal-{method}-{gains}",
            CalibrationOptions(method=method, frame_gains=gains, filter_steps=0, filter_scenes=16,  # type: ignore[arg-type]
                               predict=False),
            report=False,
        )
        m = out.bundle.meta["metrics"]
        val = [v for v in out.validation if v.label.startswith("val_")]
        rows.append({
            "case": case.name,
            "method": f"{method}/gains {gains}",
            "psnr_db": float(np.mean([v.psnr_db for v in val])),
            "ssim": float(np.mean([v.ssim for v in val])),
            "psnr_by_scene": {v.label: round(v.psnr_db, 2) for v in val},
            "iterations": [s["iterations"] for s in m["solve"]],
            "seconds": round(time.perf_counter() - t0, 1),
        })
    return rows


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The benchmark's options (shared by ``thintact bench calibration`` and ``python -m``)."""
    p.add_argument("--profile", default="virtual-mini")
    p.add_argument("--cases", nargs="*", help="case names (default all: " + ", ".join(c.name for c in CASES).replace("%", "%%") + ")")
    p.add_argument("--json", metavar="FILE", help="also write the rows as JSON")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m thintact_sdk.calibration.stress_cases", description=__doc__)
    add_arguments(p)
    return run(p.parse_args(argv))


def run(args: argparse.Namespace) -> int:
    """Run the cases of ``args`` and print one row per case and method."""
    from thintact_sdk.host.machine import machine_summary

    profile = load_profile(args.profile)
    cases = [c for c in CASES if not args.cases or c.name in args.cases]
    print(f"# {machine_summary()}")
    print(f"# profile {profile.name}: sensor {profile.sensor.rows}x{profile.sensor.cols}, scene "
          f"{profile.scene.rows}x{profile.scene.cols}; validation {', '.join(DEFAULT_VALIDATION)}")
    rows: list[dict[str, Any]] = []
    for case in cases:
        methods = [("paper", "off"), ("lsq", "off")]
        with tempfile.TemporaryDirectory() as tmp:
            for r in run_case(profile, case, methods, Path(tmp)):
                rows.append(r)
                print(f"{r['case']:32s} {r['method']:15s} PSNR {r['psnr_db']:6.2f} dB  SSIM {r['ssim']:.3f}  "
                      f"iterations {r['iterations']}  {r['seconds']} s", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
