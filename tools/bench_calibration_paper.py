#!/usr/bin/env python
"""Time and memory of each calibration stage on the paper's design, at the paper's size or a
fraction of it (issue 36).

Renders a slit-scan recording of ``thintact-paper`` (its mask and geometry; virtual camera
and display; one frame per pattern, the profile's noise) with the sensor and the scene both
divided by ``--scale`` per axis (1: the paper's 1024 × 1280 sensor and 400 × 512 scene, every
pattern of the wizard's plan), then runs ``calibrate_recording`` on it in a child process and
reads the per-stage wall time and peak memory the calibration writes (``metrics.stages``) and
the child's own peak resident memory (``VmHWM``). Every child starts with an empty backend
cache (``THINTACT_CACHE_DIR``), as a station's first unit of a shape does. ``--baseline DIR`` runs a second child on
the ``thintact_sdk`` of another source tree (e.g. the previous commit's, written by
``git archive <rev> thintact_sdk | tar -x -C DIR``), in the same invocation, so the two are
compared on the same host load.

``--wizard`` runs the pipelined wizard instead (``calibrate_with_wizard``: virtual camera and
display rendering every pattern, one frame each; the capture worker compresses and solves the
slits and simulates the prediction's design while it captures) and reports the capture's time,
the time from the last pattern to the bundle (``metrics.after_last_pattern_s``) and the stages
after it; with ``--docs`` its table goes between ``<!-- bench_calibration_wizard -->`` markers.

Usage::

    python tools/bench_calibration_paper.py --out /tmp/bench --scale 4 --baseline /tmp/base
    python tools/bench_calibration_paper.py --out /tmp/bench --scale 2 --docs docs/calibration.md
    python tools/bench_calibration_paper.py --out /tmp/bench --scale 1 --wizard --docs docs/calibration.md

With ``--docs`` the table replaces the text between the markers
``<!-- bench_calibration_paper -->`` and ``<!-- /bench_calibration_paper -->`` of that file
(appended when absent). Prints the table; exit status 0.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from docs_block import host_line, write_block

MARK_OPEN, MARK_CLOSE = "<!-- bench_calibration_paper -->", "<!-- /bench_calibration_paper -->"


def _profile(scale: int) -> Any:
    from thintact_sdk.formats.profiles import Profile, load_profile

    d = load_profile("thintact-paper").contract_dict()
    d["name"] = f"thintact-paper-div{scale}"
    d["sensor"]["rows"], d["sensor"]["cols"] = 1024 // scale, 1280 // scale
    d["scene"] = {"rows": 400 // scale, "cols": 512 // scale, "pixel_pitch_um": 31.5}
    d["display"] = {"plugin": "virtual", "pixel_pitch_um": 31.5, "settle_s": 0.0}
    d["camera"] = {"plugin": "virtual", "settings": {}}
    return Profile.model_validate(d)


def render(out: Path, scale: int) -> float:
    """Write the recording (every pattern of the wizard's plan) into ``out``; seconds taken."""
    from thintact_sdk.calibration.plan import build_plan
    from thintact_sdk.formats.recording import RecordingWriter
    from thintact_sdk.simulation.noise import signal_to_dn
    from thintact_sdk.simulation.simulator import Simulator

    prof = _profile(scale)
    sim = Simulator(prof)
    g = sim.reference_gain()
    gains = [g, 0.93 * g, 0.82 * g]
    rng = np.random.default_rng(0)
    writer = RecordingWriter(out, prof)
    plan = build_plan(prof)
    t = time.monotonic()
    for k, step in enumerate(plan, start=1):
        x = step.make()
        x3 = x if x.ndim == 3 else np.repeat(x[..., None], 3, axis=-1)
        dn = signal_to_dn(sim.predict_signal_dn(x3.astype(np.float64), gains), prof.noise, rng)
        writer.add(dn.astype(np.float32), x, label=step.label, kind=step.kind, frames=1, exposure_us=10000.0)
        if k % 50 == 0 or k == len(plan):
            print(f"  rendered {k}/{len(plan)} patterns ({time.monotonic() - t:.0f} s)", file=sys.stderr, flush=True)
    return time.monotonic() - t


class MemorySampler:
    """The process's resident memory split, sampled every ``period_s`` on a daemon thread:
    the peak of its private pages (``RssAnon``: arrays) and of its file-backed pages
    (``RssFile``: the recording's frames mapped from disk, page cache the kernel can drop),
    MiB. ``VmHWM`` counts both."""

    def __init__(self, period_s: float = 0.25) -> None:
        import threading

        self.peak = {"RssAnon": 0.0, "RssFile": 0.0}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(period_s,), daemon=True)
        self._thread.start()

    def _run(self, period_s: float) -> None:
        while not self._stop.wait(period_s):
            with open("/proc/self/status") as f:
                for line in f:
                    key = line.split(":")[0]
                    if key in self.peak:
                        self.peak[key] = max(self.peak[key], int(line.split()[1]) / 1024)

    def stop(self) -> dict[str, float]:
        self._stop.set()
        self._thread.join()
        return {"peak_private_mib": round(self.peak["RssAnon"]), "peak_file_mib": round(self.peak["RssFile"])}


def child(rec: Path, out: Path, result: Path) -> None:
    """Calibrate ``rec`` into ``out`` and write the stages and figures to ``result`` (JSON)."""
    from thintact_sdk.calibration.pipeline import CalibrationOptions, calibrate_recording
    from thintact_sdk.formats.recording import Recording

    t = time.monotonic()
    sampler = MemorySampler()
    o = calibrate_recording(Recording(rec), out, CalibrationOptions(),
                            status=lambda s: print("  " + s, file=sys.stderr, flush=True))
    m = o.bundle.meta["metrics"]
    with open("/proc/self/status") as f:
        peak = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 2**20
    result.write_text(json.dumps({
        "seconds": time.monotonic() - t, "peak_gib": peak, "stages": m["stages"],
        "psnr_db": m["psnr_db"], "predicted_psnr_db": m["predicted_psnr_db"], **sampler.stop()}))


def wizard_child(scale: int, out: Path, result: Path) -> None:
    """Run the pipelined wizard (virtual camera and display, one frame per pattern) into
    ``out`` and write its stages, the capture's time and the time after the last pattern."""
    from thintact_sdk.calibration.pipeline import CalibrationOptions
    from thintact_sdk.calibration.sessions import calibrate_with_wizard

    t = time.monotonic()
    sampler = MemorySampler()
    o = calibrate_with_wizard(_profile(scale), out, CalibrationOptions(), frames=1,
                              status=lambda s: print(f"  [{time.monotonic() - t:.0f} s] " + s,
                                                     file=sys.stderr, flush=True))
    total = time.monotonic() - t
    m = o.bundle.meta["metrics"]
    with open("/proc/self/status") as f:
        peak = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 2**20
    result.write_text(json.dumps({
        "seconds": total, "after_last_pattern_s": m["after_last_pattern_s"],
        "capture_s": total - m["after_last_pattern_s"], "peak_gib": peak, "stages": m["stages"],
        "pipelined": m.get("pipelined"), "psnr_db": m["psnr_db"],
        "predicted_psnr_db": m["predicted_psnr_db"], **sampler.stop()}))


def _fresh_cache(out: Path) -> Path:
    """An empty cache directory for a child (``THINTACT_CACHE_DIR``): the decoders' backends are
    measured as on a station's first unit, not taken from an earlier run's cache."""
    cache = out.with_name(out.name + "_cache")
    shutil.rmtree(cache, ignore_errors=True)
    cache.mkdir(parents=True)
    return cache


def _run_child(rec: Path, out: Path, tree: Path | None) -> dict[str, Any]:
    """Run :func:`child` in a fresh interpreter; ``tree``: import ``thintact_sdk`` from there."""
    result = out.with_suffix(".json")
    cmd = [sys.executable, __file__, "--child", str(rec), str(out), str(result)]
    env = dict(os.environ)
    env["THINTACT_CACHE_DIR"] = str(_fresh_cache(out))
    if tree is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(tree.resolve())] + [p for p in [env.get("PYTHONPATH")] if p])
    subprocess.run(cmd, check=True, env=env)
    return dict(json.loads(result.read_text()))


def _host() -> str:
    return host_line()


def table(scale: int, runs: dict[str, dict[str, Any]], render_s: float, load: tuple[float, float]) -> str:
    names = list(next(iter(runs.values()))["stages"][i]["stage"] for i in range(len(next(iter(runs.values()))["stages"])))
    head = "| stage | " + " | ".join(f"{k}: s (peak MiB)" for k in runs) + " |\n|---|" + "---|" * len(runs) + "\n"
    rows = []
    for i, name in enumerate(names):
        cells = [f"{r['stages'][i]['seconds']:.1f} ({r['stages'][i]['peak_rss_mib']:.0f})" for r in runs.values()]
        rows.append(f"| {name} | " + " | ".join(cells) + " |")
    rows.append("| **total** | " + " | ".join(f"**{r['seconds']:.1f}** ({1024 * r['peak_gib']:.0f})" for r in runs.values()) + " |")
    rows.append("| of the peak: private (arrays) / file-backed (mapped frames), MiB | " + " | ".join(
        f"{r.get('peak_private_mib', float('nan')):.0f} / {r.get('peak_file_mib', float('nan')):.0f}"
        for r in runs.values()) + " |")
    figures = []
    for k, r in runs.items():
        pred = r["predicted_psnr_db"] or {}
        figures.append(f"{k}: held-out mean {np.mean(list(r['psnr_db'].values())):.3f} dB, "
                       f"predicted mean {np.mean(list(pred.values())) if pred else float('nan'):.3f} dB")
    return (f"Sensor {1024 // scale} × {1280 // scale}, scene {400 // scale} × {512 // scale} "
            f"(the paper's divided by {scale} per axis), {400 // scale + 512 // scale} slits, one frame per "
            f"pattern; {f'recording rendered in {render_s:.0f} s' if render_s else 'recording of an earlier run'}. Host: {_host()}; load average "
            f"{load[0]:.1f} before, {load[1]:.1f} after.\n\n" + head + "\n".join(rows) + "\n\n"
            + "; ".join(figures) + ".\n")


WIZ_OPEN, WIZ_CLOSE = "<!-- bench_calibration_wizard -->", "<!-- /bench_calibration_wizard -->"


def _wizard(a: argparse.Namespace) -> int:
    out, result = a.out / f"wizard_div{a.scale}", a.out / f"wizard_div{a.scale}.json"
    # a fresh unit: the wizard resumes a capture it finds in its output directory
    shutil.rmtree(out, ignore_errors=True)
    load0 = os.getloadavg()[0]
    subprocess.run([sys.executable, __file__, "--wizard-child", str(a.scale), str(out), str(result)],
                   check=True, env=dict(os.environ, THINTACT_CACHE_DIR=str(_fresh_cache(out))))
    r = json.loads(result.read_text())
    def name(s: dict[str, Any]) -> str:
        done = s.get("pipelined")
        if not isinstance(done, dict):
            return str(s["stage"])
        return f"{s['stage']} (during the capture: " + ", ".join(f"{k} {v:.1f} s" for k, v in done.items()) + ")"

    rows = "\n".join(f"| {name(s)} | {s['start_s']:.1f} | {s['seconds']:.1f} | {s['peak_rss_mib']:.0f} |"
                     for s in r["stages"])
    pred = r["predicted_psnr_db"] or {}
    text = (f"Pipelined wizard, sensor {1024 // a.scale} × {1280 // a.scale}, scene {400 // a.scale} × "
            f"{512 // a.scale}, virtual camera and display, one frame per pattern. Host: {_host()}; load "
            f"average {load0:.1f} before, {os.getloadavg()[0]:.1f} after. Capture (rendering every "
            f"pattern) {r['capture_s']:.0f} s; **from the last pattern to the bundle "
            f"{r['after_last_pattern_s']:.0f} s**; peak memory {r['peak_gib']:.2f} GiB (the whole "
            f"process, capture included; sampled peaks: private {r.get('peak_private_mib', float('nan')):.0f} MiB, "
            f"file-backed {r.get('peak_file_mib', float('nan')):.0f} MiB).\n\n| stage after the capture | starts at s | s | peak MiB |\n"
            f"|---|---|---|---|\n{rows}\n\nheld-out mean {np.mean(list(r['psnr_db'].values())):.3f} dB, "
            f"predicted mean {np.mean(list(pred.values())) if pred else float('nan'):.3f} dB.\n")
    print(text)
    if a.docs is not None:
        write_block(a.docs, WIZ_OPEN, WIZ_CLOSE, text)
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, help="working directory (recording and bundles)")
    ap.add_argument("--scale", type=int, default=4, help="divide the paper's sensor and scene by this per axis")
    ap.add_argument("--baseline", type=Path, metavar="DIR",
                    help="also run the thintact_sdk of this source tree (the code to compare with)")
    ap.add_argument("--docs", type=Path, help="write the table into this markdown file between the markers")
    ap.add_argument("--wizard", action="store_true",
                    help="run the pipelined wizard (virtual camera and display) instead: the capture's "
                    "time, the time from the last pattern to the bundle and the stages after it")
    ap.add_argument("--child", nargs=3, metavar=("REC", "OUT", "RESULT"), help=argparse.SUPPRESS)
    ap.add_argument("--wizard-child", nargs=3, metavar=("SCALE", "OUT", "RESULT"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        child(Path(a.child[0]), Path(a.child[1]), Path(a.child[2]))
        return 0
    if a.wizard_child:
        wizard_child(int(a.wizard_child[0]), Path(a.wizard_child[1]), Path(a.wizard_child[2]))
        return 0
    if a.out is None or a.scale < 1 or 400 % a.scale or 512 % a.scale or 1024 % a.scale or 1280 % a.scale:
        print("--out is needed, and --scale must divide 400, 512, 1024 and 1280", file=sys.stderr)
        return 2
    a.out.mkdir(parents=True, exist_ok=True)
    if a.wizard:
        return _wizard(a)
    rec = a.out / f"rec_div{a.scale}"
    render_s = 0.0 if (rec / "manifest.json").is_file() else render(rec, a.scale)
    load0 = os.getloadavg()[0]
    runs = {"this code": _run_child(rec, a.out / f"cal_div{a.scale}", None)}
    if a.baseline is not None:
        runs["baseline"] = _run_child(rec, a.out / f"cal_div{a.scale}_base", a.baseline)
    text = table(a.scale, runs, render_s, (load0, os.getloadavg()[0]))
    print(text)
    if a.docs is not None:
        write_block(a.docs, MARK_OPEN, MARK_CLOSE, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
