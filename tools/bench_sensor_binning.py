"""Time ``t2s-closed-form`` on the paper device's operator, unbinned and on the sensor binned
2 × 2, interleaved in one run (same load), numpy float32, two kernel threads and one.

It also times raw Bayer mosaic → decoded frame with the binned decoder both ways the Sensor
can take (``raw_two_pass``: binned 2 × 2 into the measurement, then again 2 × 2 by the decoder;
``raw_one_pass``: the mosaic binned 4 × 4 per colour site straight to the decoder's input,
a decoder declaring ``input = "binned"``, :class:`thintact_sdk.interfaces.Decoder`), in the same rounds.

The operator is the directly generated one (the frame time depends only on the shapes and the
kept modes, not on how the matrices were obtained); τ is the bench's (0.3 × the coding power
gives the same kept modes). Run it under ``OPENBLAS_CORETYPE=Haswell`` to time OpenBLAS's AVX2
kernels on an AVX-512 host (a proxy for an AVX2-only CPU's arithmetic, not its clocks).

Usage::

    python tools/bench_sensor_binning.py [--profile thintact-paper] [--rounds 5] [--frames 10]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable

import numpy as np

from thintact_sdk.algorithms import SystemMatrices, coding_power
from thintact_sdk.device.cameras import to_measurement
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.frames import RawFrame
from thintact_sdk.host.compute_threads import single_threaded_kernels
from thintact_sdk.host.machine import machine_summary
from thintact_sdk.host.roofline import measure_sgemm_gflops
from thintact_sdk.pixels.bayer import mosaic_from_rgb, planar_frame
from thintact_sdk.reconstruction.decoders import ArrayBackend, T2SClosedFormDecoder
from thintact_sdk.reconstruction.decoders.sensor_binning import (
    SensorBinnedDecoder,
    bin_frame,
    bin_system_matrices,
)
from thintact_sdk.reconstruction.direct_generation import direct_system_matrices


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", default="thintact-paper")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--frames", type=int, default=10)
    args = ap.parse_args()
    profile = load_profile(args.profile)
    po, qo, pc, qc = direct_system_matrices(np.asarray(profile.mask.phi, float), profile)
    c = 3
    stack = lambda a: np.repeat(np.asarray(a, np.float32)[None], c, 0)  # noqa: E731
    sm = SystemMatrices(stack(po), stack(qo), stack(pc), stack(qc))
    tau = 0.3 * coding_power(sm)
    full = T2SClosedFormDecoder(sm, tau, ArrayBackend("numpy", "float32"))
    binned = SensorBinnedDecoder(T2SClosedFormDecoder(bin_system_matrices(sm), tau / 4, ArrayBackend("numpy", "float32")),
                                 sm.sensor_shape, c)
    r, s = sm.sensor_shape
    frame = planar_frame(r, s, c)
    frame[...] = np.random.default_rng(0).integers(64, 4000, (r, s, c))
    n, _ = sm.scene_shape
    raw = RawFrame(mosaic_from_rgb(frame.astype(np.uint16)), 0, 1, "BayerRG12")

    buffer = planar_frame(r // 2, s // 2, c)

    def before() -> None:  # the path before the one-pass binning: the black level subtracted at the bin
        m = to_measurement(raw, profile)
        binned.inner.decode(bin_frame(m.data, 2, buffer, m.black_level_dn))

    def two_pass() -> None:
        m = to_measurement(raw, profile)
        binned.decode(m.data, m.black_level_dn)

    def one_pass() -> None:
        m = to_measurement(raw, profile, sensor_bin=binned.sensor_bin)
        binned.decode(m.data, m.black_level_dn)

    def time_ms(fn: Callable[[], object]) -> float:
        ts = []
        for _ in range(args.frames):
            t0 = time.perf_counter()
            fn()
            ts.append((time.perf_counter() - t0) * 1e3)
        return float(np.median(ts))

    out: dict[str, object] = {"profile": profile.name, "openblas_coretype": os.environ.get("OPENBLAS_CORETYPE", ""),
                              "gflop": {"unbinned": full.gemm_flops() / 1e9, "bin2": binned.gemm_flops() / 1e9}}
    for threads in ("2 threads", "1 thread"):
        rows: dict[str, list[float]] = {"unbinned": [], "bin2": [], "raw_before": [], "raw_two_pass": [],
                                        "raw_one_pass": [],
                                        "sgemm_gflops": []}
        ctx = single_threaded_kernels() if threads == "1 thread" else None
        if ctx is not None:
            ctx.__enter__()
        try:
            for dec in (full, binned):
                dec.decode(frame, 64.0)  # warm
            for _ in range(args.rounds):
                rows["sgemm_gflops"].append(measure_sgemm_gflops(c, n, r, s))
                rows["unbinned"].append(time_ms(lambda: full.decode(frame, 64.0)))
                rows["bin2"].append(time_ms(lambda: binned.decode(frame, 64.0)))
                rows["raw_before"].append(time_ms(before))
                rows["raw_two_pass"].append(time_ms(two_pass))
                rows["raw_one_pass"].append(time_ms(one_pass))
        finally:
            if ctx is not None:
                ctx.__exit__(None, None, None)
        out[threads] = {k: [round(v, 2) for v in vals] for k, vals in rows.items()}
        out[threads]["ratio_bin2_over_unbinned"] = round(  # type: ignore[index]
            float(np.median(np.array(rows["bin2"]) / np.array(rows["unbinned"]))), 3)
        out[threads]["ratio_raw_one_over_two_pass"] = round(  # type: ignore[index]
            float(np.median(np.array(rows["raw_one_pass"]) / np.array(rows["raw_two_pass"]))), 3)
        out[threads]["ratio_raw_one_pass_over_before"] = round(  # type: ignore[index]
            float(np.median(np.array(rows["raw_one_pass"]) / np.array(rows["raw_before"]))), 3)
    out["load_average"] = os.getloadavg()
    out["machine"] = machine_summary()
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
