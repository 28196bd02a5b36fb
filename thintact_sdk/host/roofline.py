"""How close a computation runs to this host's matrix-product speed (the roofline ratio).

A decoder's frame time is compared with the time its GEMM floating-point operations would
take at the float32 GEMM rate measured on this host, in the same run and at the decoder's
own largest product shape (so load from other processes affects both alike).
"""

from __future__ import annotations

import time

import numpy as np


def measure_sgemm_gflops(batch: int, m: int, k: int, n: int, repeats: int = 5, seed: int = 0) -> float:
    """Median GFLOP/s of numpy float32 ``(batch × m × k) @ (batch × k × n)``.

    Parameters
    ----------
    batch, m, k, n
        Product shape (e.g. ``3, 408, 1024, 1280`` for a paper-size decoder's first product).
    repeats
        Timed repetitions after one warm-up.
    """
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((batch, m, k), dtype=np.float32)
    b = rng.standard_normal((batch, k, n), dtype=np.float32)
    out = np.empty((batch, m, n), np.float32)
    np.matmul(a, b, out=out)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        np.matmul(a, b, out=out)
        times.append(time.perf_counter() - t0)
    return 2.0 * batch * m * k * n / float(np.median(times)) / 1e9


def roofline_ratio(measured_ms: float, gemm_flops: float, sgemm_gflops: float) -> float:
    """``measured time / (gemm_flops at sgemm_gflops)``: 1 means the frame costs no more than
    its matrix products at the host's GEMM rate."""
    return measured_ms / (gemm_flops / (sgemm_gflops * 1e9) * 1e3)


def measure_torch_gemm_gflops(device: str, batch: int, m: int, k: int, n: int,
                              dtype: str = "float32", repeats: int = 5, seed: int = 0) -> float:
    """Median GFLOP/s of a torch ``(batch × m × k) @ (batch × k × n)`` on ``device``.

    The rate of an accelerator (``"cuda"``, ``"mps"``) measured the way its decoders run:
    operands already on the device, each product synchronised before the clock stops.
    ``dtype`` is a torch dtype name (``"float32"``, ``"bfloat16"``); float32 products use
    torch's default precision setting (TF32 only where the caller allowed it).
    """
    import torch

    gen = torch.Generator(device="cpu").manual_seed(seed)
    dt = getattr(torch, dtype)
    a = torch.randn((batch, m, k), generator=gen).to(device=device, dtype=dt)
    b = torch.randn((batch, k, n), generator=gen).to(device=device, dtype=dt)

    def sync() -> None:
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        elif device.startswith("mps"):
            torch.mps.synchronize()

    out = a @ b
    sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        torch.matmul(a, b, out=out)
        sync()
        times.append(time.perf_counter() - t0)
    return 2.0 * batch * m * k * n / float(np.median(times)) / 1e9
