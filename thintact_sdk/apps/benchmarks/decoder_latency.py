"""Reconstruction speed and quality on the paper's device (thintact-paper), one run.

Per-frame latency from a binned raw frame (1024 × 1280 × 3, black level included) in memory
to the 400 × 512 × 3 scene, both as the Sensor hands it to the decoder (float32, channel-planar
from the Bayer binning) and as an interleaved uint16 frame (a stored recording), of the non-iterative decoders (the paper's joint-filter
decoder and this SDK's exact closed form of the full T2S problem) on every backend that is real
on this host (numpy and torch float32; torch bfloat16 products only where the CPU has them
natively; CUDA/MPS when present), each with its GEMM FLOPs and roofline ratio (frame time over
those FLOPs at the float32 GEMM rate measured in the same run), the work before mode
truncation for comparison, and the backend a decoder would choose here; the iterative T2S baseline (Nesterov, 800 iterations)
timed over a few iterations and extrapolated; their ratio; PSNR/SSIM of all of them on white,
USAF and GelSight scenes simulated with the full simulator plus sensor noise; MLS vs the
masks plugin's GA design (uniformity of the white reconstruction and PSNR).

It also decodes with an oracle in place of the joint filter (the true open term ``Po X Qoᵀ``
subtracted from the noisy measurement, same τ): the best any open-term filter can do, so the
gap between the paper's decoder and iterative-800 splits into the filter's share and the
method's (the coding term alone carries little of a uniform scene on an MLS mask).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

NAME = "reconstruct"
"""The benchmark's name: ``thintact bench reconstruct``."""
SCENES = (("white", 0), ("usaf", 0), ("gelsight", 20))
ORACLE = "thintact-noniterative, oracle filter (true open term removed)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Command-line options of ``thintact bench reconstruct``."""
    from thintact_sdk.apps.cli.argtypes import positive_int

    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--profile", default="thintact-paper", help="device profile (default thintact-paper)")
    p.add_argument("--repeats", type=positive_int, default=12, help="timed frames per decoder (median reported)")
    p.add_argument("--train-scenes", type=positive_int, default=16, help="filter training scenes")
    p.add_argument("--iterative-probe", type=positive_int, default=3,
                   help="iterations of the plain iterative decoder actually timed (then extrapolated)")
    p.add_argument("--no-mask-compare", action="store_true", help="skip the comparison with stored optimised mask designs")


def _median_ms(fn: Callable[[], Any], repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


def _uniformity(white_recon: np.ndarray) -> dict[str, float]:
    """White-scene uniformity: coefficient of variation and min/max ratio of the mean image
    (central 90 % of the field, per-pixel mean over channels)."""
    g = np.asarray(white_recon, np.float64).mean(axis=2)
    n, m = g.shape
    c = g[n // 20 : n - n // 20, m // 20 : m - m // 20]
    return {"cv": float(c.std() / max(c.mean(), 1e-12)),
            "min_over_max": float(c.min() / max(c.max(), 1e-12))}


class _Device:
    """Simulator, two-term fit, measurements and trained filter of one profile."""

    def __init__(self, profile: Any, train_count: int, say: Callable[[str], None]) -> None:
        from thintact_sdk.device.virtual_bench import signal_scale_dn
        from thintact_sdk.reconstruction.filter_training import (
            make_training_data,
            train_joint_filter,
            training_scenes,
        )
        from thintact_sdk.reconstruction.t2s import SystemMatrices
        from thintact_sdk.reconstruction.virtual_bundle import coding_power, simulate_measurements
        from thintact_sdk.simulation.scenes import make_scene
        from thintact_sdk.simulation.simulator import Simulator

        self.profile = profile
        say(f"{profile.name}: simulator and two-term fit")
        sim = Simulator(profile)
        self.scale = signal_scale_dn(profile, {})
        self.sm = SystemMatrices.two_term_fit(sim, scale_dn=self.scale)
        n, m = self.sm.scene_shape
        self.scenes = [make_scene(name, n, m, i) for name, i in SCENES]
        say(f"{profile.name}: simulating noisy measurements")
        self.signal, _ = simulate_measurements(sim, self.scale, self.scenes, profile.noise, seed=1)
        nz = profile.noise
        self.raw = [np.clip(np.round(s + nz.black_level_dn), 0, nz.saturation_dn).astype(np.uint16)
                    for s in self.signal]
        say(f"{profile.name}: training the joint filter (closed form, {train_count} scenes)")
        data = make_training_data(self.sm, training_scenes(n, m, train_count), noise=profile.noise)
        self.filter = train_joint_filter(self.sm, data=data, low_block="auto", phi_s_rank=4, steps=0)
        del data
        self.unit = coding_power(self.sm)
        self.open_signal = [self.sm.forward_open(x) for x in self.scenes]


def _as_binned(raw: np.ndarray) -> np.ndarray:
    """``raw`` (``R × S × 3`` uint16) as the Sensor hands a binned frame to its decoder:
    float32 DN in channel-planar storage (:func:`thintact_sdk.pixels.bayer.planar_frame`)."""
    from thintact_sdk.pixels.bayer import planar_frame

    frame = planar_frame(*raw.shape)
    frame[...] = raw
    return frame


def _raw_call(dec: Any, raw: np.ndarray, black: float) -> Callable[[], np.ndarray]:
    """A zero-argument call decoding one uint16 raw frame (what is timed), black level folded in."""
    return lambda: dec.decode(raw, black)


def _sensor_call(dec: Any, frame: np.ndarray, black: float, b: int) -> Callable[[], np.ndarray]:
    """A zero-argument call decoding ``frame`` (``R × S × C`` float32 planar) as the Sensor
    feeds ``dec`` (``Decoder.decode(frame, black_level_dn)``): the ``b × b`` block means for a
    decoder declaring ``input = "binned"`` (``b > 1``, the binning done here once, as the Bayer
    stage does it), else the frame itself."""
    if b == 1:
        return _raw_call(dec, frame, black)
    from thintact_sdk.pixels.bayer import block_mean

    small = block_mean(frame, b)
    return lambda: dec.decode(small, black)


def _from_signal(dec: Any, black: float) -> Callable[[np.ndarray], np.ndarray]:
    """Decode a noisy signal (DN above black) through the raw path: add black, round to uint16."""
    return lambda y: dec.decode(np.clip(np.round(y + black), 0, 65535).astype(np.uint16), black)


def _quality(decode: Callable[[np.ndarray], np.ndarray], dev: _Device,
             signals: list[np.ndarray] | None = None) -> dict[str, Any]:
    from thintact_sdk.reconstruction.metrics import psnr, ssim

    out: dict[str, Any] = {}
    for (name, _), x, y in zip(SCENES, dev.scenes, signals or dev.signal, strict=True):
        xh = np.clip(decode(y), 0.0, 1.0)
        out[name] = {"psnr_db": round(float(psnr(xh, x)), 2), "ssim": round(float(ssim(xh, x)), 3)}
        if name == "white":
            out[name]["uniformity"] = {k: round(v, 4) for k, v in _uniformity(xh).items()}
    return out


def _best_tau(dec: Any, dev: _Device) -> float:
    """τ (coarse grid × the coding power) maximising mean PSNR over the USAF and GelSight frames
    (the white frame is kept for the uniformity figure); leaves ``dec`` set to it."""
    from thintact_sdk.reconstruction.tau_sweep import tune_decoder_tau

    grid = [rel * dev.unit for rel in (0.01, 0.03, 0.1, 0.3, 1.0, 3.0)]
    return tune_decoder_tau(dec, grid, list(dev.signal[1:]), list(dev.scenes[1:])).tau


def run(args: argparse.Namespace) -> int:
    """Run the benchmark and print its figures (table or ``--json``)."""
    from rich.console import Console

    from thintact_sdk.apps.benchmarks.accelerator_split import accelerator_split
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.host.compute_threads import prepare_worker_thread, single_threaded_kernels
    from thintact_sdk.host.machine import host_capabilities, machine_summary
    from thintact_sdk.host.roofline import measure_sgemm_gflops, roofline_ratio
    from thintact_sdk.pixels.bayer import block_mean
    from thintact_sdk.reconstruction.decoders import (
        ArrayBackend,
        NonIterativeDecoder,
        T2SClosedFormDecoder,
        T2SIterativeDecoder,
    )
    from thintact_sdk.reconstruction.decoders.backend_cache import BackendCache
    from thintact_sdk.reconstruction.decoders.backend_candidates import candidate_specs
    from thintact_sdk.reconstruction.decoders.backend_selection import Probe, select_backend
    from thintact_sdk.reconstruction.decoders.sensor_binning import (
        SENSOR_BIN,
        binnable_build,
        binning_possible,
    )

    console = Console(stderr=True)
    t_start = time.perf_counter()
    with console.status("starting") as status:
        say = status.update
        profile = load_profile(args.profile)
        dev = _Device(profile, args.train_scenes, say)
        black = profile.noise.black_level_dn
        say("choosing tau")
        tau_ni = _best_tau(NonIterativeDecoder(dev.sm, dev.filter, dev.unit), dev)
        tau_cf = _best_tau(T2SClosedFormDecoder(dev.sm, dev.unit), dev)
        result: dict[str, Any] = {
            "profile": profile.name,
            "sensor": list(dev.sm.sensor_shape), "scene": list(dev.sm.scene_shape),
            "two_term_fit_relative_error": dev.sm.meta["fit_relative_error"][0],
            "filter": {"low_block": dev.filter.meta["low_block"], "phi_s_rank": 4,
                       "training_loss": dev.filter.meta["final_loss"], "training": "closed form only"},
            "tau": {"thintact-noniterative": tau_ni, "t2s-closed-form / iterative": tau_cf},
            "latency_ms": {}, "latency_ms_from_uint16": {}, "quality": {},
        }
        sensor_bin = SENSOR_BIN if binning_possible(dev.sm.sensor_shape, dev.sm.scene_shape) else 1
        builders: dict[str, Callable[..., Any]] = {
            "thintact-noniterative": partial(NonIterativeDecoder, dev.sm, dev.filter, tau_ni),
            # t2s-closed-form, or on the sensor binned b × b (τ / b², the same objective)
            "t2s-closed-form": binnable_build(dev.sm, tau_cf, T2SClosedFormDecoder),
        }
        caps = host_capabilities()
        result["host"] = caps.lines()
        specs = candidate_specs(caps)
        specs_t2s = candidate_specs(caps, sensor_bin=sensor_bin)
        result["roofline"] = {}
        raw = dev.raw[2]
        binned = _as_binned(raw)
        (r, s), (n, _) = dev.sm.sensor_shape, dev.sm.scene_shape
        # (tag, backend, mode_rtol, sensor bin): every real backend of this host with the default
        # mode truncation, numpy float32 with every mode (the work before truncation), and
        # t2s-closed-form on the sensor binned 2 × 2 where the sensor oversamples the scene
        runs: list[tuple[str, Any, float | None, int]] = [
            (spec.key, spec.make(), None, spec.sensor_bin) for spec in specs_t2s]
        runs.append(("numpy-float32, all modes", ArrayBackend("numpy", "float32"), 0.0, 1))
        for tag, be, rtol, b in runs:
            say(f"timing non-iterative decoders ({tag})")
            for label, build in builders.items():
                if b > 1 and label != "t2s-closed-form":
                    continue
                kw = {} if rtol is None else {"mode_rtol": rtol}
                dec = build(be, b, **kw) if b > 1 else build(be, **kw)
                key = f"{label} [{tag}]"
                sgemm = measure_sgemm_gflops(dev.sm.channels, n, r, s)  # same run, same load
                # what the Sensor hands this decoder: a sensor-binning decoder gets the mosaic
                # binned straight to R/b × S/b (one pass, in the Bayer stage), the others R × S
                timed = _sensor_call(dec, binned, black, b)
                ms = _median_ms(timed, args.repeats)
                ms_u16 = _median_ms(_raw_call(dec, raw, black), args.repeats)
                result["latency_ms"][key] = round(ms, 2)
                result["latency_ms_from_uint16"][key] = round(ms_u16, 2)
                result["quality"][key] = _quality(_from_signal(dec, black), dev)
                flops = dec.gemm_flops()
                with single_threaded_kernels():  # a stream's decode worker: one kernel thread
                    prepare_worker_thread()
                    sgemm_1 = measure_sgemm_gflops(dev.sm.channels, n, r, s)
                    ms_1 = _median_ms(timed, args.repeats)
                result["roofline"][key] = {
                    "gemm_gflop": float(f"{flops / 1e9:.4g}"), "sgemm_gflops": float(f"{sgemm:.4g}"),
                    "ratio": float(f"{roofline_ratio(ms, flops, sgemm):.4g}"),
                    "ratio_from_uint16": float(f"{roofline_ratio(ms_u16, flops, sgemm):.4g}"),
                    "one_thread": {"ms": round(ms_1, 2), "sgemm_gflops": float(f"{sgemm_1:.4g}"),
                                   "ratio": float(f"{roofline_ratio(ms_1, flops, sgemm_1):.4g}")},
                    "kept_modes": list(dec.kept_modes)}
                if be.name == "torch" and str(be.device) != "cpu":
                    # an accelerator: the bus reported apart from the device's work (as fed,
                    # and from the camera's uint16 where the decoder takes the full sensor)
                    split = result.setdefault("accelerator", {})
                    fed = binned if b == 1 else block_mean(binned, b)
                    # a sensor-binning decoder's work is its inner decoder's on the binned frame
                    split[key] = accelerator_split(dec if b == 1 else dec.inner, fed, black, args.repeats)
                    if b == 1:
                        split[f"{key} from uint16"] = accelerator_split(dec, raw, black, args.repeats)
        say("backend selection as a decoder does it (measured now, not cached)")
        probes = [Probe(dev.raw[i], black, dev.scenes[i]) for i in (1, 2)]
        result["backend_choice"] = {}
        with tempfile.TemporaryDirectory() as tmp:
            for label, build in builders.items():
                _, choice = select_backend(build, lambda: probes, specs_t2s if label == "t2s-closed-form" else specs,
                                           f"bench|{label}",
                                           cache=BackendCache(Path(tmp) / "backends.json"))
                result["backend_choice"][label] = choice.summary()
        say("oracle open-term removal")
        oracle = NonIterativeDecoder(dev.sm, None, tau_ni)
        result["quality"][ORACLE] = _quality(
            oracle.decode, dev, [y - yo for y, yo in zip(dev.signal, dev.open_signal, strict=True)])
        say("iterative T2S: timing a few iterations")
        it800: dict[str, float] = {}
        for form in ("gram", "direct"):
            it = T2SIterativeDecoder(dev.sm, tau_cf, iterations=args.iterative_probe, power_iterations=3,
                                     gradient=form)
            y_cf = it.xp.channels_first(dev.signal[2])
            probe_ms = _median_ms(partial(it.solve, y_cf), 2)
            setup_ms = _median_ms(partial(it.adjoint, y_cf), 2)
            per_iter = max(probe_ms - setup_ms, 0.0) / args.iterative_probe
            it800[form] = setup_ms + 800 * per_iter
            result[f"iterative800_{form}"] = {
                "latency_ms_extrapolated": round(it800[form], 1),
                "per_iteration_ms": round(per_iter, 2),
                "measured": f"{args.iterative_probe} iterations ({form} gradient, numpy float32), "
                            "median of 2 runs, extrapolated linearly to 800",
            }
        result["iterative800"] = result["iterative800_gram"]
        say("iterative T2S: 800 iterations for quality (same iterates, decoder coordinates)")
        ref = T2SClosedFormDecoder(dev.sm, tau_cf, ArrayBackend("numpy", "float64"))
        result["quality"]["t2s-iterative-800"] = _quality(lambda y: ref.iterate(y, 800), dev)
        best_ni = min((v, k) for k, v in result["latency_ms"].items() if "noniterative" in k)
        best_cf = min((v, k) for k, v in result["latency_ms"].items() if "closed-form" in k)
        result["speedup_vs_iterative800"] = {
            f"{name} vs {form} form": round(it800[form] / ms, 0)
            for ms, name in (best_ni, best_cf) for form in ("gram", "direct")}
        if not args.no_mask_compare:
            result["mask_compare"] = _mask_compare(profile, dev, result, args, say)
        result["machine"] = machine_summary()
        result["wall_s"] = round(time.perf_counter() - t_start, 1)
    _print(result, args.json)
    return 0


def _mask_compare(profile: Any, dev: _Device, result: dict[str, Any], args: argparse.Namespace,
                  say: Callable[[str], None]) -> dict[str, Any]:
    """The profile's mask (keyed by its ``mask.design``, ``profile`` when unnamed) against
    every design a mask component has stored for this device
    (:meth:`~thintact_sdk.interfaces.MaskDesigner.stored_design`), keyed by the component's
    name; ``designs`` says so when no mask component has one."""
    from thintact_sdk.device.registry import get_registry

    out: dict[str, Any] = {profile.mask.design or "profile": {
        k: result["quality"][f"{k} [numpy-float32]"] for k in ("thintact-noniterative", "t2s-closed-form")}}
    registry = get_registry()
    for name in sorted(registry.components("mask")):
        try:
            stored = registry.create("mask", name).stored_design(profile.name)
        except Exception as err:  # noqa: BLE001 - a broken design is reported, not fatal
            out[name] = f"no stored design ({type(err).__name__}: {err})"
            continue
        if stored is not None:
            out[name] = _design_quality(profile, *stored, args, say)
    if len(out) == 1:
        out["designs"] = f"no mask component stores a design for {profile.name}"
    return out


def _design_quality(profile: Any, mask: Any, record: dict[str, Any], args: argparse.Namespace,
                    say: Callable[[str], None]) -> dict[str, Any]:
    """PSNR/SSIM of both closed forms on the device with ``mask`` in place of the profile's."""
    from thintact_sdk.formats.profiles import profile_from_dict
    from thintact_sdk.reconstruction.decoders import NonIterativeDecoder, T2SClosedFormDecoder

    d = profile.contract_dict()
    d["mask"] = {**d["mask"], "phi": [int(v) for v in mask.phi], "design": record.get("design", "stored"),
                 "feature_um": mask.feature_um or d["mask"]["feature_um"]}
    if mask.phi_rows is not None:
        d["mask"]["phi_rows"] = [int(v) for v in mask.phi_rows]
    other = _Device(profile_from_dict(d, where="stored mask design"), args.train_scenes, say)
    ni = NonIterativeDecoder(other.sm, other.filter, other.unit)
    cf = T2SClosedFormDecoder(other.sm, other.unit)
    _best_tau(ni, other)
    _best_tau(cf, other)
    return {
        "thintact-noniterative": _quality(ni.decode, other),
        "t2s-closed-form": _quality(cf.decode, other),
        "design": {k: record.get(k) for k in ("design", "K", "feature_um") if k in record},
    }


def _print(result: dict[str, Any], as_json: bool) -> None:
    if as_json:
        print(json.dumps(result, indent=1))
        return
    from rich.console import Console
    from rich.table import Table

    con = Console(markup=False)  # keys such as "[torch-bfloat16]" are text, not markup
    con.print(f"thintact bench reconstruct — {result['profile']} "
              f"(sensor {result['sensor']}, scene {result['scene']}), wall {result['wall_s']} s", style="bold")
    con.print(f"two-term fit error vs simulator: {result['two_term_fit_relative_error']:.2%}; "
              f"filter: {result['filter']}; tau: {result['tau']}")
    for line in result.get("host", []):
        con.print(f"host: {line}")
    tab = Table("decoder [backend]", "ms/frame", "GFLOP", "roofline", "1 thread: ms, roofline", "from uint16",
                "white dB", "USAF dB", "GelSight dB", "SSIM G", "white CV")
    roof = result.get("roofline", {})
    for key, q in result["quality"].items():
        ms = result["latency_ms"].get(key)
        if key == "t2s-iterative-800":
            ms = result["iterative800"]["latency_ms_extrapolated"]
        rf = roof.get(key)
        one = rf["one_thread"] if rf else None
        u16 = result.get("latency_ms_from_uint16", {}).get(key)
        tab.add_row(key, f"{ms:.1f}" if ms is not None else "-",
                    f"{rf['gemm_gflop']:.2f}" if rf else "-",
                    f"{rf['ratio']:.2f} @ {rf['sgemm_gflops']:.0f} GFLOP/s" if rf else "-",
                    f"{one['ms']:.1f}, {one['ratio']:.2f} @ {one['sgemm_gflops']:.0f}" if one else "-",
                    f"{u16:.1f} ms ({rf['ratio_from_uint16']:.2f})" if rf and u16 is not None else "-",
                    str(q["white"]["psnr_db"]), str(q["usaf"]["psnr_db"]), str(q["gelsight"]["psnr_db"]),
                    str(q["gelsight"]["ssim"]), str(q["white"]["uniformity"]["cv"]))
    con.print(tab)
    con.print("roofline: frame time / (GEMM FLOPs at this host's float32 GEMM rate, measured just "
              "before each decoder at its largest product shape); ms/frame from the frame as the "
              "Sensor hands it over (float32, channel-planar; for -bin2 the mosaic binned straight to "
              "R/2 × S/2 in the Bayer stage), 'from uint16' from an interleaved uint16 frame of full "
              "size (a stored recording; -bin2 bins it first); '1 thread' as in a stream's decode worker")
    for key, acc in result.get("accelerator", {}).items():
        con.print(f"{key} on {acc['device']} ({acc['input']}): upload {acc['upload_ms']:.2f} ms, "
                  f"on the device {acc['device_ms']:.2f} ms (roofline {acc['roofline']} @ "
                  f"{acc['gemm_gflops']:.0f} GFLOP/s), download {acc['download_ms']:.2f} ms")
    for label, summary in result.get("backend_choice", {}).items():
        con.print(f"backend chosen for {label}: {summary}")
    for form in ("gram", "direct"):
        it = result[f"iterative800_{form}"]
        con.print(f"iterative-800 ({form} gradient): {it['latency_ms_extrapolated']:.0f} ms; {it['measured']}")
    con.print(f"speed-up vs iterative-800: {result['speedup_vs_iterative800']}")
    if "mask_compare" in result:
        con.print("mask comparison (numpy float32): " + json.dumps(result["mask_compare"]))
    con.print(f"machine: {result['machine']}")
