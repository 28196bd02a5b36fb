"""``thintact bench reconstruct`` end to end on the small virtual device."""

from __future__ import annotations

import argparse
import json

from thintact_sdk.apps.benchmarks import decoder_latency as reconstruct
from thintact_sdk.host.machine import host_capabilities
from thintact_sdk.reconstruction.decoders.sensor_binning import binning_possible


def test_bench_reconstruct_runs_on_virtual_mini(capsys, monkeypatch) -> None:
    parser = argparse.ArgumentParser()
    reconstruct.add_arguments(parser)
    args = parser.parse_args(["--json", "--profile", "virtual-mini", "--repeats", "2",
                              "--train-scenes", "8", "--iterative-probe", "2"])
    assert reconstruct.run(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["profile"] == "virtual-mini"
    keys = set(out["latency_ms"])
    assert {"thintact-noniterative [numpy-float32]", "t2s-closed-form [torch-float32]",
            "t2s-closed-form [numpy-float32, all modes]"} <= keys
    # t2s-closed-form is also timed on the sensor binned 2 × 2 where the sensor oversamples
    # the scene: about half the GEMM work, its quality reported like every other row
    if binning_possible(tuple(out["sensor"]), tuple(out["scene"])):
        binned = "t2s-closed-form [numpy-float32-bin2]"
        assert binned in keys and "thintact-noniterative [numpy-float32-bin2]" not in keys
        assert out["roofline"][binned]["gemm_gflop"] < 0.7 * out["roofline"]["t2s-closed-form [numpy-float32]"]["gemm_gflop"]
        assert out["quality"][binned]["gelsight"]["psnr_db"] > 5
        assert "numpy-float32-bin2" in out["backend_choice"]["t2s-closed-form"]
    # bfloat16 products are timed only where the CPU has them (emulated: ~100x slower)
    assert any("bfloat16" in k for k in keys) == host_capabilities().native_bf16
    for key in ("thintact-noniterative [numpy-float32]", "t2s-closed-form [numpy-float32]"):
        roof = out["roofline"][key]
        assert roof["gemm_gflop"] > 0 and roof["sgemm_gflops"] > 0 and roof["ratio"] > 0
        assert roof["one_thread"]["ratio"] > 0 and roof["ratio_from_uint16"] > 0
        assert out["latency_ms_from_uint16"][key] > 0
    assert set(out["backend_choice"]) == {"thintact-noniterative", "t2s-closed-form"}
    assert all("numpy-float32" in v for v in out["backend_choice"].values())
    assert any("AVX" in line or "SIMD" in line for line in out["host"])
    assert all(v > 0 for v in out["latency_ms"].values())
    q = out["quality"]
    for name in ("white", "usaf", "gelsight"):
        assert q["t2s-iterative-800"][name]["psnr_db"] > 5
    # the closed form solves the same problem as iterative-800, to convergence
    assert q["t2s-closed-form [numpy-float32]"]["gelsight"]["psnr_db"] >= \
        q["t2s-iterative-800"]["gelsight"]["psnr_db"] - 0.1
    # the trained joint filter is close to the oracle that removes the true open term
    for name in ("usaf", "gelsight"):
        assert q["thintact-noniterative [numpy-float32]"][name]["psnr_db"] >= \
            q[reconstruct.ORACLE][name]["psnr_db"] - 1.0
    assert out["iterative800"]["latency_ms_extrapolated"] > 0  # timings themselves are load-dependent
    # the profile's own mask under its design's name, and the masks plugin's stored GA design
    assert {"random", "ga"} <= set(out["mask_compare"])
    assert "cores" in out["machine"]
    # the table prints the backend tags as text (rich would take "[numpy-float32]" for markup)
    monkeypatch.setenv("COLUMNS", "220")
    reconstruct._print(out, as_json=False)
    table = capsys.readouterr().out
    assert "thintact-noniterative [torch-float32]" in table and "decoder [backend]" in table
    assert "roofline" in table and "backend chosen for t2s-closed-form" in table
    assert "1 thread" in table and "from uint16" in table


def test_decoders_take_the_binned_planes_without_a_copy_and_decode_them_alike() -> None:
    """The Bayer binning hands the decoder channel-planar float32 storage; the channel-first
    operand is that storage itself (no per-frame conversion pass), and the result equals
    the one from an interleaved copy of the same frame."""
    import numpy as np

    from thintact_sdk.algorithms import SystemMatrices
    from thintact_sdk.pixels.bayer import bin_bayer
    from thintact_sdk.reconstruction.decoders import ArrayBackend, T2SClosedFormDecoder

    rng = np.random.default_rng(3)
    mosaic = rng.integers(60, 4000, size=(32, 40)).astype(np.uint16)
    frame = bin_bayer(mosaic)
    assert np.moveaxis(frame, -1, 0).flags.c_contiguous
    for name in ("numpy", "torch"):
        xp = ArrayBackend(name, "float32")
        planes = xp.channels_first(frame, gemm=True)
        shared = np.shares_memory(planes, frame) if name == "numpy" else planes.data_ptr() == frame.ctypes.data
        assert shared
    sm = SystemMatrices(0.1 * rng.standard_normal((3, 16, 12)), 0.1 * rng.standard_normal((3, 20, 14)),
                        rng.standard_normal((3, 16, 12)), rng.standard_normal((3, 20, 14)))
    dec = T2SClosedFormDecoder(sm, 2.0)
    interleaved = np.ascontiguousarray(frame)
    np.testing.assert_allclose(dec.decode(frame, 64.0), dec.decode(interleaved, 64.0), rtol=1e-5, atol=1e-6)
    assert frame.base is not None and np.array_equal(frame, interleaved)  # the input was not written to
