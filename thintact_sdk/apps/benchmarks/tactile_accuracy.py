"""Tactile accuracy and latency through the full lensless path (paper §VI-C table).

1. Depth: a chamfered prism and a 4 mm sphere pressed 0.25/0.50/0.75/1.00 mm at random
   places and rotations, rendered by the tactile simulator, imaged by the virtual camera
   (simulator + noise), reconstructed by the profile's decoder and interpreted with a LUT
   calibrated the same way (ball presses through the same path). Per-image RMS over the
   pixels deeper than the contact threshold, mean over presses (paper's method).
2. Markers: displacement RMS error after shearing a pressed sphere in three frames.
3. Latency: raw Bayer frame → tactile frame on the paper's device (1024×1280 binned,
   400×512 scene), per frame and streamed.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.apps.cli.argtypes import positive_float, positive_int, seed
from thintact_sdk.formats.safe_yaml import dump_json

NAME = "tactile"
"""The benchmark's name: ``thintact bench tactile``."""

DEPTH_GOAL_MM = 0.05
MARKER_GOAL_MM = 0.02
LATENCY_GOAL_MS = 60.0
FPS_GOAL = 25.0
P99_OVER_P50_GOAL = 2.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", default="virtual-finger", help="device for the accuracy tests")
    p.add_argument("--latency-profile", default="thintact-paper",
                   help="device for the latency test (default: the paper's)")
    p.add_argument("--presses", type=positive_int, default=3,
                   help="random presses per indenter and depth (default 3)")
    p.add_argument("--calibration-presses", type=positive_int, default=12,
                   help="ball presses for the LUT calibration through the path")
    p.add_argument("--marker-presses", type=positive_int, default=6)
    p.add_argument("--latency-frames", type=positive_int, default=20)
    p.add_argument("--decoder", help="decoder plugin (default: each profile's decoder.plugin)")
    p.add_argument("--tau", type=positive_float,
                   help="Tikhonov tau (DN²) for the accuracy decoder instead of the bundle's")
    p.add_argument("--latency-bundle", type=Path,
                   help="calibration bundle directory for the latency test's device (default: the "
                        "profile's; without one, --decoder or flatcam on an in-memory bundle of the "
                        "directly generated matrices)")
    p.add_argument("--skip-latency", action="store_true")
    p.add_argument("--force-presses", type=positive_int, default=12,
                   help="simulated presses to fit and (as many again) to test force/slip")
    p.add_argument("--skip-force", action="store_true", help="skip the force/slip rows")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--json", type=Path, help="also write the figures to this JSON file")


def _progress() -> Any:
    from rich.progress import Progress

    return Progress(transient=True)


def accuracy(args: argparse.Namespace, out: dict[str, Any]) -> None:
    """Depth table and marker error on ``args.profile`` through its virtual camera."""
    from thintact_sdk.device.cameras import camera_is_simulated
    from thintact_sdk.device.sensor import Sensor
    from thintact_sdk.errors import ThinTactError
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.calibration.device import calibrate_virtual, scene_slot
    from thintact_sdk.tactile.calibration.evaluation import (
        PAPER_TABLE_MM,
        evaluate_depth,
        evaluate_markers,
    )

    profile = load_profile(args.profile)
    if not camera_is_simulated(profile):
        raise ThinTactError(f"--profile {args.profile}: the accuracy test needs a virtual camera")
    settings = {"slot": "bench-tactile", "fps": 0, "seed": args.seed}
    from thintact_sdk.device.registry import get_registry
    from thintact_sdk.errors import CalibrationError

    decoder_name = args.decoder or (profile.decoder.plugin if profile.decoder else "?")
    dec_settings = dict(profile.decoder.settings) if profile.decoder is not None else {}
    decoder_note = "calibration bundle"
    if args.tau is not None:
        dec_settings["tau"] = args.tau
        decoder_note += f", tau {args.tau:g} from --tau"
    elif "tau" in dec_settings:
        # τ is in DN² of the bundle's matrices; a profile value written in other units
        # would override the bundle's calibrated τ
        decoder_note += f"; the profile's decoder.settings.tau {dec_settings.pop('tau')} ignored"
    try:
        decoder = get_registry().create("decoder", decoder_name, profile, dec_settings)
    except CalibrationError as err:
        decoder = None
        decoder_note = f"{err}; instead: "
    with Sensor(profile, camera_settings=settings, decoder=decoder) as sensor, _progress() as bar:
        slot = scene_slot(sensor)
        if decoder is None:
            decoder_name = args.decoder or _filterless_decoder()
            sensor.decoder, tau = _simulator_decoder(sensor, slot, decoder_name)
            decoder_note += f"in-memory two-term fit of the simulator, tau {tau:g} chosen on " \
                            "4 calibration-ball presses"
        task = bar.add_task("LUT calibration", total=args.calibration_presses)
        t0 = time.perf_counter()
        sensor.lut = calibrate_virtual(
            sensor, args.calibration_presses, seed=args.seed,
            progress=lambda i, n: bar.update(task, completed=i, total=n),
        )
        calib_s = time.perf_counter() - t0
        task = bar.add_task("depth table", total=1)
        rows = evaluate_depth(sensor, slot.set, presses=args.presses, seed=args.seed + 1,
                              progress=lambda i, n: bar.update(task, completed=i, total=n))
        task = bar.add_task("markers", total=args.marker_presses)
        markers = evaluate_markers(sensor, slot.set, presses=args.marker_presses,
                                   seed=args.seed + 2,
                                   progress=lambda i, n: bar.update(task, completed=i, total=n))
        from thintact_sdk.diagnosis.tactile.lensless import evaluate_concealed

        bar.add_task("concealed tactile effects", total=None)
        t0 = time.perf_counter()
        concealed, concealed_diag = evaluate_concealed(sensor, slot.set, presses=args.presses,
                                                       seed=args.seed + 3)
        concealed_s = time.perf_counter() - t0
    print(f"\nDepth accuracy through the lensless path ({profile.name}: "
          f"{profile.sensor.rows}x{profile.sensor.cols} sensor, {profile.scene.rows}x"
          f"{profile.scene.cols} scene at {profile.scene.pixel_pitch_um / 1000:.3f} mm; decoder "
          f"{decoder_name} ({decoder_note}); LUT from "
          f"{args.calibration_presses} 3 mm ball presses through the same path, {calib_s:.1f} s; "
          f"{args.presses} random presses per row)")
    print(f"{'indenter':16s} {'depth':>6s} {'RMS sensor':>11s} {'RMS scene':>10s} "
          f"{'paper real':>11s} {'Real2Sim':>9s}")
    for r in rows:
        real, r2s = PAPER_TABLE_MM.get((r.indenter, r.depth_mm), (float("nan"),) * 2)
        print(f"{r.indenter:16s} {r.depth_mm:5.2f}mm {r.rms_mm:9.3f}mm {r.rms_scene_mm:8.3f}mm "
              f"{real:9.3f}mm {r2s:7.3f}mm")
    worst = max(r.rms_mm for r in rows)
    mean = float(np.mean([r.rms_mm for r in rows]))
    print(f"mean {mean:.3f} mm, worst {worst:.3f} mm (goal ≤ {DEPTH_GOAL_MM} mm: "
          f"{'met' if worst <= DEPTH_GOAL_MM else 'NOT met'})")
    print(f"\nMarker displacement: RMS error {markers.rms_mm:.4f} mm over "
          f"{markers.tracked_fraction:.0%} of markers tracked (true displacements up to "
          f"{markers.max_true_mm:.2f} mm, {args.marker_presses} sheared presses in 3 steps); "
          f"shear direction error {markers.direction_error_deg:.1f}° "
          f"(goal ≤ {MARKER_GOAL_MM} mm: {'met' if markers.rms_mm <= MARKER_GOAL_MM else 'NOT met'})")
    _print_concealed(concealed, concealed_diag, concealed_s)
    out["concealed"] = {"rows": [r.__dict__ for r in concealed], "seconds": concealed_s,
                        "findings": concealed_diag["findings"]}
    out["decoder"] = f"{decoder_name} ({decoder_note})"
    out["depth"] = [r.__dict__ for r in rows]
    out["depth_mean_mm"], out["depth_worst_mm"] = mean, worst
    out["markers"] = markers.__dict__
    out["lut_calibration_s"] = calib_s


def _print_concealed(rows: list[Any], diag: dict[str, Any], seconds: float) -> None:
    from thintact_sdk.diagnosis.tactile.lensless import (
        CONCEALED_EXPOSURE_SD,
        CONCEALED_FIELD,
        CONCEALED_GAMMA,
    )

    named = ", ".join(f"{f['effect']} {f['params']}" for f in diag["findings"]) or "nothing"
    print(f"\nConcealed tactile effects through the lensless path (4 mm sphere; scenes × field "
          f"1 + {CONCEALED_FIELD[0, 1]:g}y {CONCEALED_FIELD[0, 2]:+g}x (R; G, B alike), exposure "
          f"sd {CONCEALED_EXPOSURE_SD:g}, emission γ {CONCEALED_GAMMA:g}; diagnosis on 8 "
          f"reconstructed 3 mm-ball presses (plain and concealed), markers masked, χ²/dof "
          f"{diag['baseline']['chi2_per_dof']:.2f} → {diag['final']['chi2_per_dof']:.2f}; "
          f"named: {named}; {seconds:.1f} s)")
    print(f"{'depth':>6s} {'no effects':>11s} {'concealed':>10s} {'corrected':>10s}")
    for r in rows:
        print(f"{r.depth_mm:5.2f}mm {r.plain_mm:9.3f}mm {r.concealed_mm:8.3f}mm {r.corrected_mm:8.3f}mm")


def _filterless_decoder() -> str:
    """The first calibration decoder that needs no joint filter (traits
    ``calibration-candidate`` without ``joint-filter``): the closed-form T2S decoder."""
    from thintact_sdk.calibration.validation import calibration_decoders, needs_joint_filter

    return next(n for n in calibration_decoders() if not needs_joint_filter(n))


def _simulator_decoder(sensor: Any, slot: Any, name: str) -> tuple[Any, float]:
    """A decoder for a virtual sensor without a calibration bundle: the two-term fit of its
    simulator (REC's ``SystemMatrices.two_term_fit``), no filter (the closed-form T2S
    decoder needs none), and the Tikhonov τ that best reconstructs the membrane (markers
    included) in a few calibration-ball presses (not the test presses)."""
    from thintact_sdk.device.registry import get_registry
    from thintact_sdk.reconstruction.bundle import CalibrationBundle
    from thintact_sdk.reconstruction.t2s import SystemMatrices
    from thintact_sdk.simulation.simulator import Simulator, white_level_gain
    from thintact_sdk.tactile import TactileSimulator, random_ball_presses

    profile = sensor.profile
    sim = Simulator(profile)
    try:
        from thintact_sdk.device.virtual_bench import signal_scale_dn

        scale = signal_scale_dn(profile, sensor.camera_settings)
    except ImportError:
        scale = white_level_gain(sim)
    sm = SystemMatrices.two_term_fit(sim, scale_dn=scale)
    flat = TactileSimulator.for_profile(profile).flat().scene
    shots = []
    for scene in [flat] + [s.scene for s, _ in random_ball_presses(profile, 4, seed=97)]:
        slot.set(scene)
        shots.append((scene, sensor.read_measurement()))
    slot.set(None)
    best: tuple[float, float, Any] | None = None
    for tau in (1000.0, 2500.0, 5000.0, 10000.0, 20000.0):
        bundle = CalibrationBundle.create(profile, sm, None, tau=tau, source="simulator")
        dec = get_registry().create("decoder", name, profile, {"bundle": bundle, "tau": tau})
        err = np.mean([np.mean((np.asarray(dec.decode(m.signal())) - sc) ** 2)
                       for sc, m in shots])
        if best is None or err < best[0]:
            best = (float(err), tau, dec)
    assert best is not None
    return best[2], best[1]


def _latency_decoder(profile: Any, name: str | None = None,
                     bundle_dir: Path | None = None) -> tuple[Any, Any, str]:
    """``(decoder, system_matrices or None, how)``: the decoder ``name`` (default the
    profile's) from the bundle in ``bundle_dir`` or the profile's bundle, or, without one, a
    bundle of the paper's directly generated matrices made in memory (seconds to build; the
    simulator fit of a 1024×1280 device takes minutes) with ``name`` when given, else the
    closed-form Tikhonov decoder (``flatcam``: the paper's solve without the joint filter).
    The system matrices are returned where the frames should be rendered with them (a bundle
    given by directory, or the in-memory one)."""
    from thintact_sdk.calibration.validation import default_decoder
    from thintact_sdk.device.registry import get_registry
    from thintact_sdk.errors import CalibrationError
    from thintact_sdk.reconstruction.decoders.components import make_flatcam

    cfg = profile.decoder
    given = name
    name = name or (cfg.plugin if cfg is not None else default_decoder())
    settings = dict(cfg.settings) if cfg is not None else {}
    if bundle_dir is not None:
        from thintact_sdk.reconstruction.bundle import CalibrationBundle

        loaded = CalibrationBundle.load(bundle_dir)
        decoder = get_registry().create("decoder", name, profile, {**settings, "bundle": loaded})
        return decoder, loaded.system_matrices, f"calibration bundle {bundle_dir}"
    try:
        return get_registry().create("decoder", name, profile, settings), None, "calibration bundle"
    except CalibrationError:
        pass
    from thintact_sdk.reconstruction.bundle import CalibrationBundle
    from thintact_sdk.reconstruction.t2s import SystemMatrices
    from thintact_sdk.simulation.noise import default_white_level_dn

    nz = profile.noise
    sm = SystemMatrices.direct(profile, scale_dn=default_white_level_dn(nz))
    tau = float(settings.get("tau", 0.01)) * float(np.linalg.norm(sm.Pc[0], 2) *
                                                   np.linalg.norm(sm.Qc[0], 2)) ** 2
    bundle = CalibrationBundle.create(profile, sm, None, tau=tau, source="simulator")
    # the profile's decoder settings (backend, gemm_dtype, ...) apply; tau was used above
    fallback = {k: v for k, v in settings.items() if k != "tau"}
    fallback["bundle"] = bundle
    if given is not None:
        decoder = get_registry().create("decoder", given, profile, fallback)
        return decoder, sm, f"no bundle on disk: {given} on an in-memory bundle of the directly generated matrices"
    decoder = make_flatcam(profile, fallback)
    return decoder, sm, (f"no bundle: {decoder.name} closed-form Tikhonov (no joint filter) on the "
                         "directly generated matrices")


def latency(args: argparse.Namespace, out: dict[str, Any]) -> None:
    """Raw Bayer → TactileFrame on ``args.latency_profile``, single frames and streamed."""
    from thintact_sdk.device.sensor import Sensor
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.frames import RawFrame
    from thintact_sdk.pixels.bayer import mosaic_from_rgb
    from thintact_sdk.simulation.noise import signal_to_dn
    from thintact_sdk.tactile import Sphere, TactileSimulator, scene_level_lut

    profile = load_profile(args.latency_profile)
    t0 = time.perf_counter()
    decoder, sm, how = _latency_decoder(profile, args.decoder, getattr(args, "latency_bundle", None))
    setup_decoder_s = time.perf_counter() - t0
    tsim = TactileSimulator.for_profile(profile)
    rng = np.random.default_rng(args.seed)
    scenes = [tsim.flat().scene] + [
        tsim.press(Sphere(2.0), d, (x, 0.0)).scene for d, x in ((0.5, -2.0), (0.8, 1.0))
    ]
    if sm is None:  # the bundle's device: its matrices are in the decoder's bundle
        from thintact_sdk.simulation.simulator import Simulator, white_level_gain

        sim = Simulator(profile)
        gain = white_level_gain(sim)
        signals = [sim.forward(sc) * gain for sc in scenes]
    else:
        signals = [sm.forward(sc) for sc in scenes]
    raws = []
    for i, sig in enumerate(signals):
        dn = signal_to_dn(np.clip(sig, 0, None), profile.noise, rng)
        raws.append(RawFrame(mosaic_from_rgb(dn.astype(np.uint16)), 0, i + 1, "BayerRG12"))
    lut = scene_level_lut(profile)
    sensor = Sensor(profile, lut=lut, decoder=decoder)
    stages: dict[str, list[float]] = {"bin": [], "decode": [], "interpret": [], "total": []}
    for k in range(args.latency_frames):
        raw = raws[k % len(raws)]
        raw.frame_id = k + 1
        with sensor.single_frame_kernels():  # the kernel threads read() decodes with
            t0 = time.perf_counter()
            m = sensor.decoder_input(raw)  # binned once, straight to a binned decoder's input
            t1 = time.perf_counter()
            img = sensor.reconstruct(m)
            t2 = time.perf_counter()
            sensor.interpreter.interpret(img, raw.timestamp_ns, raw.frame_id)
            t3 = time.perf_counter()
        for key, v in zip(stages, (t1 - t0, t2 - t1, t3 - t2, t3 - t0), strict=True):
            stages[key].append(v * 1e3)
    med = {k: float(np.median(v)) for k, v in stages.items()}
    p95 = float(np.percentile(stages["total"], 95))
    fps = _streamed_fps(profile, raws, sensor, args.latency_frames)
    print(f"\nLatency raw Bayer {2 * profile.sensor.rows}x{2 * profile.sensor.cols} → tactile "
          f"frame on {profile.name} ({profile.scene.rows}x{profile.scene.cols} scene; decoder "
          f"{type(decoder).__name__} ({how}), set up in {setup_decoder_s:.1f} s; tactile "
          f"work grid {sensor.interpreter.work.rows}x{sensor.interpreter.work.cols}; "
          f"{args.latency_frames} frames)")
    print(f"median {med['total']:.1f} ms (bin {med['bin']:.1f}, decode {med['decode']:.1f}, "
          f"interpret {med['interpret']:.1f}), p95 {p95:.1f} ms "
          f"(goal ≤ {LATENCY_GOAL_MS:.0f} ms: {'met' if med['total'] <= LATENCY_GOAL_MS else 'NOT met'})")
    print(f"streamed (pipelined capture / bin / decode / interpret): {fps['fps']:.1f} tactile "
          f"frames/s from a camera delivering {fps['camera_fps']:.0f} frames/s, "
          f"{fps['consumer_dropped'] + fps['skipped']:.0f} frames skipped by newest-frame delivery "
          f"(goal ≥ {FPS_GOAL:.0f} fps: {'met' if fps['fps'] >= FPS_GOAL else 'NOT met'})")
    ratio = fps["latency_p99_ms"] / fps["latency_p50_ms"]
    print(f"end-to-end latency camera timestamp → frame delivered: p50 {fps['latency_p50_ms']:.1f} ms, "
          f"p99 {fps['latency_p99_ms']:.1f} ms (p99/p50 {ratio:.2f}, goal ≤ {P99_OVER_P50_GOAL:.0f}: "
          f"{'met' if ratio <= P99_OVER_P50_GOAL else 'NOT met'}); longest wait of a finished frame for "
          f"the consumer {fps['waited_ms_max']:.1f} ms (one camera period {1e3 / fps['camera_fps']:.1f} ms); "
          f"decoder warm-up before the first read {fps['warm_up_s']:.1f} s")
    out["latency_ms"] = {"median": med, "p95_total": p95, "decoder_source": how,
                         "decoder": _decoder_summary(sensor.decoder)}
    out["stream"] = fps


def _decoder_summary(decoder: Any) -> str:
    """Decoder name, the backend the selection chose and the sensor binning it solves on."""
    from thintact_sdk.interfaces import DecoderInput

    choice = getattr(decoder, "backend_choice", None)
    backend = getattr(choice, "chosen", None) or repr(getattr(decoder, "xp", ""))
    return f"{getattr(decoder, 'name', type(decoder).__name__)} [{backend}] sensor_bin {DecoderInput.of(decoder).sensor_bin}"


def _streamed_fps(profile: Any, raws: list[Any], sensor: Any, frames: int,
                  budget_s: float = 10.0) -> dict[str, float]:
    """Tactile frames per second and end-to-end latency (camera timestamp → delivered, p50 /
    p99) from Sensor.stream on a camera replaying ``raws`` at 30 fps (at least 60 frames or
    ``frames``, or ``budget_s`` seconds, whichever comes first)."""
    import thintact_sdk
    from thintact_sdk.device.registry import PluginRegistry
    from thintact_sdk.device.sensor import Sensor
    from thintact_sdk.formats.profiles import CameraConfig
    from thintact_sdk.interfaces import Camera, CameraCapabilities

    camera_fps = 30.0

    class MemoryCamera(Camera):
        name = "bench-memory"

        def __init__(self) -> None:
            self._n = 0
            self._next = time.monotonic()

        def open(self) -> None:
            self._is_open = True

        def close(self) -> None:
            self._is_open = False

        def capabilities(self) -> CameraCapabilities:
            h, w = raws[0].data.shape
            return CameraCapabilities(w, h, ["BayerRG12"], "BayerRG12", camera_fps)

        def read(self, timeout_s: float = 2.0) -> Any:
            self._next += 1.0 / camera_fps
            time.sleep(max(0.0, self._next - time.monotonic()))
            self._n += 1
            raw = raws[self._n % len(raws)]
            return type(raw)(raw.data, time.monotonic_ns(), self._n, raw.pixel_format)

    class _Plugin:
        @thintact_sdk.hookimpl
        def thintact_cameras(self) -> list[thintact_sdk.Component]:
            return [thintact_sdk.Component("bench-memory", lambda p, s: MemoryCamera())]

    reg = PluginRegistry()
    reg.register(_Plugin(), "bench-memory")
    prof = profile.model_copy(
        update={"camera": CameraConfig(plugin="bench-memory"), "light": None}, deep=True
    )
    s = Sensor(prof, lut=sensor.lut, decoder=sensor.decoder, registry=reg)
    latencies: list[float] = []
    with s:
        t0 = None
        n = 0
        for frame in s.stream(max_frames=max(frames, 60) + 1, timeout_s=10.0):
            latencies.append((time.monotonic_ns() - frame.timestamp_ns) / 1e6)
            if t0 is None:
                t0 = time.perf_counter()
            else:
                n += 1
                if time.perf_counter() - t0 > budget_s:
                    break
        elapsed = time.perf_counter() - (t0 or time.perf_counter())
    return {
        "fps": n / elapsed if elapsed > 0 else float("nan"),
        "camera_fps": camera_fps,
        "skipped": float(s.stats.skipped),
        "consumer_dropped": float(s.stats.consumer_dropped),
        "processed": float(s.stats.processed),
        "latency_p50_ms": float(np.percentile(latencies, 50)),
        "latency_p99_ms": float(np.percentile(latencies, 99)),
        "waited_ms_max": s.stats.waited_ms_max,
        "warm_up_s": s.stats.warm_up_s,
        "decode_workers": float(s.stats.decode_workers),
    }


def force_slip(args: argparse.Namespace, out: dict[str, Any]) -> None:
    """Force and slip estimates against the elastic ground truth (scene level)."""
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.interpretation.force import NORMAL_FILL_GAIN, NORMAL_GAIN, SHEAR_GAIN
    from thintact_sdk.tactile.simulation.loaded_press import evaluate_force_slip

    profile = load_profile(args.profile)
    t0 = time.perf_counter()
    ev = evaluate_force_slip(profile, presses=args.force_presses, seed=args.seed)
    elapsed = time.perf_counter() - t0
    print(f"\nForce and slip ({profile.name}, scene level; truth: half-space contact solution "
          f"(Boussinesq + Cattaneo–Mindlin, E 0.3 MPa, ν 0.48, μ 1) of each simulated press; "
          f"gains fitted on {ev.presses} presses (balls R 3/8 mm, cylinder R 2.5 mm, prism "
          f"5x3 mm), tested on {ev.presses} others (balls R 4/6 mm, cylinder R 1.5 mm, prism "
          f"6x4 mm), {elapsed:.0f} s)")
    print(f"  fitted gains c_0 {ev.normal_gain:.3f}, c_1 {ev.normal_fill_gain:.3f}, "
          f"c_t {ev.shear_gain:.2f} (shipped {NORMAL_GAIN}, {NORMAL_FILL_GAIN}, {SHEAR_GAIN})")
    print(f"  normal force: relative RMS error {ev.normal_rel_rms:.1%} over "
          f"{ev.normal_range_n[0]:.2f}–{ev.normal_range_n[1]:.2f} N")
    print(f"  shear force: relative RMS error {ev.shear_rel_rms:.1%} over "
          f"{ev.shear_range_n[0]:.2f}–{ev.shear_range_n[1]:.2f} N, direction error median "
          f"{ev.shear_direction_median_deg:.0f}°, RMS {ev.shear_direction_deg:.0f}°")
    print(f"  slip ratio: MAE {ev.slip_mae:.2f}, RMS {ev.slip_rms:.2f}; incipient slip (true "
          f"0.2–0.8) flagged in {ev.slip_incipient_detected:.0%}, false alarms without "
          f"shear {ev.slip_false_alarm:.0%}")
    out["force_slip"] = {k: v for k, v in ev.__dict__.items()}
    out["force_slip"]["seconds"] = elapsed


def run(args: argparse.Namespace) -> int:
    from thintact_sdk.host.machine import machine_summary

    print(machine_summary())
    out: dict[str, Any] = {"machine": machine_summary()}
    t0 = time.perf_counter()
    accuracy(args, out)
    if not args.skip_force:
        force_slip(args, out)
    if not args.skip_latency:
        latency(args, out)
    out["wall_s"] = time.perf_counter() - t0
    import os

    load = os.getloadavg()
    print(f"\nbenchmark wall time {out['wall_s']:.0f} s; load average {load[0]:.1f} on "
          f"{os.cpu_count()} cores (timings on a shared machine are inflated by other work)")
    out["load_average"] = load[0]
    if args.json is not None:
        args.json.write_text(dump_json(out) + "\n")
    return 0
