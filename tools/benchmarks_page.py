#!/usr/bin/env python
"""Write ``docs/benchmarks.md``: the measured figures of this host, with the host and date.

Runs each measuring source below as a child process (or reads its JSON output from an
earlier run, ``--from NAME=FILE``), then writes the page: the host (CPU model, cores, SIMD
flags, GPU, the load the runs saw), the date (UTC), one section of figures per source (with
the machine line its run reported), a section per other host whose runs kept their JSON
outputs under ``docs/measurements/HOST/`` (``doctor.txt`` describing the host), and the
page's history section carried over verbatim (the older hand-measured figures, each with its
host). Nothing else on the page is written by hand.

==============  =====================================================================
source          what runs (the smallest sizes, except ``reconstruct`` at paper size)
==============  =====================================================================
reconstruct     ``thintact bench reconstruct --json --repeats 3`` (paper device)
tactile         ``thintact bench tactile --json F`` with 1 press per row, few frames
calibration     ``thintact bench calibration --cases baseline --json F``
sensor-binning  ``tools/bench_sensor_binning.py --rounds 1 --frames 2``
==============  =====================================================================

Usage::

    OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 .venv/bin/python tools/benchmarks_page.py \\
        [--from reconstruct=bench.json] [--skip calibration] [--keep-json DIR] [--out docs/benchmarks.md]

Timings depend on the host and on what else runs on it; the page says both.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

HISTORY_BEGIN = "<!-- history: carried over verbatim by tools/benchmarks_page.py -->"
HISTORY_END = "<!-- end of history -->"
THINTACT = [sys.executable, "-m", "thintact_sdk.apps.cli.main"]


def _thintact(*argv: str) -> list[str]:
    return [*THINTACT, *argv]


# -- sources: how each runs (argv; "{json}" is the file it writes, else it prints JSON) ----
SOURCES: dict[str, list[str]] = {
    "reconstruct": _thintact("bench", "reconstruct", "--json", "--repeats", "3"),
    "tactile": _thintact("bench", "tactile", "--json", "{json}", "--presses", "1",
                         "--calibration-presses", "4", "--marker-presses", "1",
                         "--latency-frames", "5", "--force-presses", "2"),
    "calibration": _thintact("bench", "calibration", "--cases", "baseline", "--json", "{json}"),
    "sensor-binning": [sys.executable, str(ROOT / "tools" / "bench_sensor_binning.py"),
                       "--rounds", "1", "--frames", "2"],
}


def run_source(name: str, keep: Path | None) -> tuple[Any, float, list[float]]:
    """Run ``name``'s command: its JSON output, the seconds it took and the 1-minute load
    averages before and after it."""
    argv = SOURCES[name]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / f"{name}.json"
        cmd = [a.replace("{json}", str(out)) for a in argv]
        print(f"[{name}] {' '.join(cmd)}", file=sys.stderr, flush=True)
        loads = [os.getloadavg()[0]]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
        seconds = time.perf_counter() - t0
        loads.append(os.getloadavg()[0])
        if proc.returncode != 0:
            raise SystemExit(f"{name} failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
        text = out.read_text() if "{json}" in argv else _last_json(proc.stdout)
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        (keep / f"{name}.json").write_text(text)
    return json.loads(text), seconds, loads


def reported_loads(data: Any) -> list[float]:
    """The 1-minute load average a source's JSON reports (``load_average``), if any."""
    v = data.get("load_average") if isinstance(data, dict) else None
    if isinstance(v, list) and v:
        v = v[0]
    return [float(v)] if isinstance(v, (int, float)) else []


def _last_json(stdout: str) -> str:
    """The JSON document a tool printed (tools may print progress lines before it): the text
    from the first line that opens an object or a list."""
    for i, line in enumerate(stdout.splitlines(keepends=True)):
        if line.startswith(("{", "[")):
            return "".join(stdout.splitlines(keepends=True)[i:])
    raise SystemExit(f"no JSON in the output: {stdout[-500:]!r}")


def load_json(path: Path) -> Any:
    """A JSON output kept in a file, progress lines before it allowed."""
    return json.loads(_last_json(path.read_text(encoding="utf-8")))


def shown_command(name: str) -> str:
    """``name``'s command as the page shows it (``thintact ...`` or ``tools/NAME.py ...``)."""
    argv = [a.replace("{json}", "FILE") for a in SOURCES[name]]
    if argv[:len(THINTACT)] == THINTACT:
        return " ".join(["thintact", *argv[len(THINTACT):]])
    return " ".join([str(Path(argv[1]).relative_to(ROOT)), *argv[2:]])


# -- rendering -----------------------------------------------------------------------------
def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.0f}" if abs(v) >= 1e4 else f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return " × ".join(_fmt(x) for x in v) if all(isinstance(x, int) for x in v) else \
            ", ".join(_fmt(x) for x in v)
    return str(v).replace("|", "\\|").replace("\n", " ")


def _pairs(d: dict[str, Any]) -> str:
    """``{"a": 1.23456, "b": 2}`` → ``a 1.235, b 2``."""
    return ", ".join(f"{k} {_fmt(v)}" for k, v in d.items())


def _table(header: tuple[str, ...], rows: list[tuple[Any, ...]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_fmt(c) for c in row) + " |" for row in rows]
    return lines


def render_reconstruct(d: dict[str, Any]) -> list[str]:
    lines = [f"Device `{d['profile']}`: sensor {_fmt(d['sensor'])} → scene {_fmt(d['scene'])}; "
             f"τ {_pairs(d['tau'])} DN². Latency is the median per frame from the binned frame as the Sensor "
             "hands it to the decoder (float32, channel-planar); \"from uint16\" from an interleaved "
             "uint16 frame; roofline is frame time over the decoder's GEMM FLOPs at the float32 "
             "GEMM rate measured in the same run (1 = the GEMMs alone); PSNR on simulated scenes "
             "with sensor noise.", ""]
    rows = []
    for key, q in d["quality"].items():
        rf = d.get("roofline", {}).get(key)
        ms = d["latency_ms"].get(key)
        if key == "t2s-iterative-800":
            ms = d["iterative800"]["latency_ms_extrapolated"]
        rows.append((f"`{key}`", "-" if ms is None else round(ms, 2),
                     "-" if rf is None else d["latency_ms_from_uint16"].get(key, "-"),
                     "-" if rf is None else rf["gemm_gflop"],
                     "-" if rf is None else f"{rf['ratio']:.3g} @ {rf['sgemm_gflops']:.0f} GFLOP/s",
                     "-" if rf is None else f"{rf['one_thread']['ms']} ms, {rf['one_thread']['ratio']:.3g}",
                     q["white"]["psnr_db"], q["usaf"]["psnr_db"], q["gelsight"]["psnr_db"]))
    lines += _table(("decoder [backend]", "ms/frame", "from uint16 (ms)", "GFLOP", "roofline",
                     "1 thread", "white dB", "USAF dB", "GelSight dB"), rows)
    lines.append("")
    for label, summary in d.get("backend_choice", {}).items():
        lines.append(f"- backend chosen for `{label}`: {summary}")
    for form in ("gram", "direct"):
        it = d.get(f"iterative800_{form}")
        if it:
            lines.append(f"- iterative-800 ({form} gradient): {it['latency_ms_extrapolated']} ms "
                         f"extrapolated ({it['measured']})")
    if "speedup_vs_iterative800" in d:
        lines.append(f"- speed-up against iterative-800: {_pairs(d['speedup_vs_iterative800'])}")
    masks = {k: v for k, v in d.get("mask_compare", {}).items() if isinstance(v, dict) and k != "design"}
    if masks:
        lines += ["", "Mask designs compared (numpy float32; white, USAF, GelSight PSNR in dB; CV of the "
                  "white reconstruction):", ""]
        rows = [(mask, f"`{dec}`", q["white"]["psnr_db"], q["usaf"]["psnr_db"], q["gelsight"]["psnr_db"],
                 q["white"].get("uniformity", {}).get("cv", "-"))
                for mask, by_dec in masks.items() for dec, q in by_dec.items()
                if isinstance(q, dict) and "white" in q]
        lines += _table(("mask", "decoder", "white dB", "USAF dB", "GelSight dB", "white CV"), rows)
        lines.append("")
    lines.append(f"- two-term fit error against the simulator: {d['two_term_fit_relative_error']:.2%}")
    acc = d.get("accelerator")
    if acc:
        lines += ["", "Accelerator backends, one frame apart (ms; roofline against the device's own "
                  "float32 GEMM rate):", ""]
        rows = [(f"`{k}`", v.get("input", ""), v.get("upload_ms"), v.get("device_ms"), v.get("download_ms"),
                 v.get("solve_ms"), v.get("gemm_gflops"), v.get("roofline")) for k, v in acc.items()]
        lines += _table(("decoder [backend]", "input", "upload", "device", "download", "solve",
                         "GEMM GFLOP/s", "roofline"), rows)
    return lines


def render_tactile(d: dict[str, Any]) -> list[str]:
    lines = [f"Decoder: {d.get('decoder', '?')}; LUT calibration {d.get('lut_calibration_s', 0):.1f} s. "
             "Depth RMS over the pixels deeper than the contact threshold, mean over presses "
             "(one press per row at this size: indicative, not a converged mean).", ""]
    rows = [(r["indenter"], r["depth_mm"], r["rms_mm"], r["rms_scene_mm"]) for r in d.get("depth", [])]
    lines += _table(("indenter", "depth (mm)", "RMS sensor (mm)", "RMS scene (mm)"), rows)
    lines.append("")
    if "depth_mean_mm" in d:
        lines.append(f"- depth RMS: mean {d['depth_mean_mm']:.3f} mm, worst {d['depth_worst_mm']:.3f} mm")
    m = d.get("markers")
    if m:
        lines.append(f"- marker displacement RMS {m['rms_mm']:.4f} mm, shear direction error "
                     f"{m['direction_error_deg']:.1f}°, {m['tracked_fraction']:.0%} tracked")
    f = d.get("force_slip")
    if f:
        lines.append("- force / slip: " + _pairs(f))
    lat = d.get("latency_ms")
    if lat:
        lines.append("- raw Bayer → tactile frame, median ms per stage: "
                     + ", ".join(f"{k} {v:.1f}" for k, v in lat["median"].items())
                     + f"; p95 total {lat['p95_total']:.1f} ms; decoder {lat.get('decoder')}")
    s = d.get("stream")
    if s:
        lines.append(f"- streamed: {s['fps']:.1f} fps from a {s['camera_fps']:g} fps camera, latency p50 "
                     f"{s['latency_p50_ms']:.1f} ms, p99 {s['latency_p99_ms']:.1f} ms, "
                     f"{s['decode_workers']:g} decode worker(s)")
    c = d.get("concealed")
    if c:
        lines.append(f"- concealed tactile effects: {len(c['rows'])} rows in {c['seconds']:.1f} s")
    return lines


def render_generic(d: Any) -> list[str]:
    """Any JSON: a list of objects as a table of their scalar fields (one row each), anything
    else as a table of its leaves by dotted path."""
    if isinstance(d, list) and d and all(isinstance(x, dict) for x in d):
        cols = [k for k, v in d[0].items() if not isinstance(v, (dict, list))]
        return _table(tuple(cols), [tuple(x.get(k, "") for k in cols) for x in d])
    rows: list[tuple[str, Any]] = []

    def walk(prefix: str, v: Any) -> None:
        if isinstance(v, dict):
            for k, x in v.items():
                if not prefix and k == "machine":
                    continue  # shown above the table
                walk(f"{prefix}.{k}" if prefix else str(k), x)
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for i, x in enumerate(v):
                walk(f"{prefix}[{i}]", x)
        else:
            rows.append((f"`{prefix}`", v))

    walk("", d)
    return _table(("figure", "value"), rows)


RENDER: dict[str, Callable[[Any], list[str]]] = {
    "reconstruct": render_reconstruct, "tactile": render_tactile,
}
TITLE = {
    "reconstruct": "`thintact bench reconstruct`: decoder latency, roofline and quality",
    "tactile": "`thintact bench tactile`: depth, markers, force / slip, latency",
    "calibration": "`thintact bench calibration`: calibration robustness (baseline case)",
    "sensor-binning": "`tools/bench_sensor_binning.py`: `t2s-closed-form` unbinned and binned 2 × 2",
}


def kept_outputs(root: Path) -> list[str]:
    """Sections for the JSON outputs other hosts' runs left under ``root`` (one folder per
    host: ``doctor.txt`` describes it, each ``*.json`` is one run; files named ``*before*``
    are comparisons kept beside them and only listed)."""
    lines: list[str] = []
    for folder in sorted(p for p in root.glob("*") if p.is_dir()):
        runs = sorted(f for f in folder.glob("*.json") if "before" not in f.name)
        if not runs:
            continue
        rel = folder.relative_to(ROOT)
        lines += [f"### `{rel}`", ""]
        doctor = folder / "doctor.txt"
        if doctor.is_file():
            lines += ["The host, as `thintact doctor` described it:", "", "```text",
                      *doctor.read_text(encoding="utf-8").strip().splitlines(), "```", ""]
        for f in runs:
            data = load_json(f)
            kind = "reconstruct" if f.name.startswith("bench_reconstruct") else \
                "tactile" if f.name.startswith("bench_tactile") else ""
            lines += [f"#### `{f.name}`", ""]
            if isinstance(data, dict) and isinstance(data.get("machine"), str):
                lines += [f"Machine as the run reported it: {data['machine']}", ""]
            lines += RENDER.get(kind, render_generic)(data)
            lines.append("")
        others = sorted(f.name for f in folder.iterdir() if f.is_file() and f not in runs
                        and f.name != "doctor.txt")
        if others:
            lines += [f"Also kept there: {', '.join(f'`{n}`' for n in others)}.", ""]
    return lines


def history(page: Path) -> list[str]:
    """The history section of the existing page, markers included (empty when there is none)."""
    if not page.is_file():
        return []
    text = page.read_text(encoding="utf-8")
    if HISTORY_BEGIN not in text or HISTORY_END not in text:
        return []
    body = text[text.index(HISTORY_BEGIN):text.index(HISTORY_END) + len(HISTORY_END)]
    return body.splitlines()


def host_lines(loads: list[float]) -> list[str]:
    """The host: CPU model, cores, SIMD flags, GPU, and the load the runs saw (each section
    adds the machine line its run reported, with the thread settings it ran under)."""
    from thintact_sdk.host.machine import host_capabilities

    caps = host_capabilities()
    cores = os.cpu_count() or 1
    lines = [f"- CPU: {caps.cpu_model}, {caps.cores} logical cores; SIMD {caps.simd}, native "
             f"bfloat16 {'yes' if caps.native_bf16 else 'no'}; flags {', '.join(caps.flags)}",
             f"- GPU: {', '.join(caps.gpus) or 'none'}"]
    if not loads:
        return [*lines, "- load average: not recorded by these runs"]
    busy = max(loads) > 0.8 * cores
    return [*lines, f"- load average (1 min) during the runs: {min(loads):.1f} to {max(loads):.1f} on "
            f"{cores} cores" + (": measured under load (other jobs were running), so timings are "
                                "inflated and vary run to run" if busy else "")]


def write_page(out: Path, found: dict[str, tuple[Any, str]], loads: list[float], note: str,
               kept: list[str]) -> None:
    now = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    old_history = history(out)
    lines = ["# Benchmarks", "",
             "<!-- generated by tools/benchmarks_page.py: edit the tool, not this page "
             "(only the history section is carried over as it is) -->", "",
             f"Written {now} by `tools/benchmarks_page.py`; each section gives its run's command "
             "and time. The host:", ""]
    lines += host_lines(loads)
    if note:
        lines += [f"- note: {note}"]
    lines += ["", "Each figure is one run; the SDK measures its decoder backend on whichever host it "
              "runs (`thintact doctor`). The figures of other hosts are in the history below.", ""]
    for name, (data, how) in found.items():
        lines += [f"## {TITLE.get(name, name)}", "", f"*{how}.*", ""]
        if isinstance(data, dict) and isinstance(data.get("machine"), str):
            lines += [f"Machine as the run reported it: {data['machine']}", ""]
        lines += RENDER.get(name, render_generic)(data)
        lines.append("")
    if kept:
        lines += ["## Other hosts: the outputs their runs kept in the repository", ""] + kept
    lines += ["## History: figures measured by hand on other hosts", ""]
    lines += old_history or [HISTORY_BEGIN, "", "(none yet)", "", HISTORY_END]
    out.write_text("\n".join(lines).rstrip() + "\n", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks.md")
    ap.add_argument("--from", dest="given", action="append", default=[], metavar="NAME=FILE",
                    help="read NAME's JSON output from FILE instead of running it")
    ap.add_argument("--skip", action="append", default=[], choices=sorted(SOURCES))
    ap.add_argument("--keep-json", type=Path, metavar="DIR", help="also keep each run's JSON here")
    ap.add_argument("--note", default="", help="one line about the conditions, printed on the page")
    ap.add_argument("--measurements", type=Path, default=ROOT / "docs" / "measurements",
                    help="folder of other hosts' kept JSON outputs, one subfolder per host")
    args = ap.parse_args(argv)
    given: dict[str, Path] = {}
    for item in args.given:
        name, sep, file = item.partition("=")
        if not sep or name not in SOURCES:
            ap.error(f"--from needs NAME=FILE with NAME one of {', '.join(SOURCES)}, got {item!r}")
        given[name] = Path(file)
    loads: list[float] = []
    found: dict[str, tuple[Any, str]] = {}
    for name in SOURCES:
        if name in args.skip:
            continue
        if name in given:
            mtime = dt.datetime.fromtimestamp(given[name].stat().st_mtime, dt.UTC)
            data = load_json(given[name])
            loads += reported_loads(data)
            found[name] = (data,
                           f"`{shown_command(name)}`, read from {given[name].name} "
                           f"(written {mtime:%Y-%m-%d %H:%M} UTC)")
        else:
            data, seconds, seen = run_source(name, args.keep_json)
            loads += seen + reported_loads(data)
            found[name] = (data, f"`{shown_command(name)}`, run {dt.datetime.now(dt.UTC):%Y-%m-%d %H:%M} UTC, "
                                 f"{seconds:.0f} s")
    kept = kept_outputs(args.measurements) if args.measurements.is_dir() else []
    write_page(args.out, found, loads, args.note, kept)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
