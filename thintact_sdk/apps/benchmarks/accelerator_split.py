"""Where an accelerator decoder's frame time goes: upload, device work, download.

A decoder on a GPU (``cuda-float32``) pays for the bus as well as for its products. For
one frame this measures, in the same run and with every step synchronised:

- ``upload_ms``: the frame's transfer to the device and its de-interleave there
  (:meth:`ArrayBackend.channels_first`);
- ``solve_ms``: the decode of a frame already on the device, up to the reconstruction
  back on the host (``N × M × C`` float32);
- ``download_ms``: that last copy alone (a ``C × N × M`` device array to the host image);
- ``device_ms``: ``solve_ms - download_ms``, the work on the device;
- ``gemm_gflops`` and ``roofline``: the device's float32 GEMM rate measured now at the
  decoder's first product shape, and ``device_ms`` over the decoder's GEMM FLOPs at that
  rate (1 means the frame costs no more than its products).

Times are medians over ``repeats`` calls after one warm-up, in milliseconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np


def _sync(device: str) -> None:
    import torch

    if device.startswith("cuda"):
        torch.cuda.synchronize()
    elif device.startswith("mps"):
        torch.mps.synchronize()


def _median_ms(fn: Callable[[], Any], device: str, repeats: int) -> float:
    fn()
    _sync(device)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        _sync(device)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3


def accelerator_split(dec: Any, frame: np.ndarray, black_dn: float, repeats: int = 20) -> dict[str, Any]:
    """The upload / device / download split of one closed-form decoder on an accelerator.

    Parameters
    ----------
    dec
        A closed-form decoder (``xp`` an :class:`ArrayBackend` on a torch accelerator,
        ``_solve(y_channels_first, black_dn)``, ``gemm_flops()``, ``channels``).
    frame
        What the decoder is fed: ``R × S × C`` DN (uint16 raw or float32), at the
        decoder's sensor shape.
    black_dn
        Black level (DN) folded into the solve.
    repeats
        Timed calls per figure.

    Returns
    -------
    dict
        ``upload_ms``, ``solve_ms``, ``download_ms``, ``device_ms``, ``gemm_gflops``,
        ``roofline``, ``input`` (dtype and shape sent), ``device``.
    """
    from thintact_sdk.host.roofline import measure_torch_gemm_gflops, roofline_ratio

    xp = dec.xp
    device = str(xp.device)
    y = xp.channels_first(frame, gemm=True)
    upload = _median_ms(lambda: xp.channels_first(frame, gemm=True), device, repeats)
    solve = _median_ms(lambda: dec._solve(y, float(black_dn)), device, repeats)
    n, m = dec._solve(y, float(black_dn)).shape[:2]
    import torch

    planes = torch.zeros((dec.channels, n, m), dtype=torch.float32, device=device)
    download = _median_ms(lambda: xp.channels_last(planes), device, repeats)
    r, s = frame.shape[:2]
    rate = measure_torch_gemm_gflops(device, dec.channels, int(dec.kept_modes[0]), r, s)
    device_ms = max(solve - download, 0.0)
    flops = float(dec.gemm_flops())
    return {
        "device": device,
        "input": f"{frame.dtype} {'x'.join(map(str, frame.shape))}",
        "upload_ms": round(upload, 3),
        "solve_ms": round(solve, 3),
        "download_ms": round(download, 3),
        "device_ms": round(device_ms, 3),
        "gemm_gflops": float(f"{rate:.4g}"),
        "roofline": float(f"{roofline_ratio(device_ms, flops, rate):.4g}") if device_ms > 0 else None,
    }
