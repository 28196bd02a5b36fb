"""The accelerator upload path of the array backend and the upload / device / download split
of ``bench reconstruct``: the same planes as the host path (run here on torch's CPU device, on
CUDA too where present)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("kind", ["uint16", "planar-float32", "float64", "uint8", "reversed-uint16"])
def test_device_planes_match_the_host_path(device: str, kind: str) -> None:
    from thintact_sdk.pixels.bayer import planar_frame
    from thintact_sdk.reconstruction.decoders import ArrayBackend

    rng = np.random.default_rng(3)
    base = rng.integers(0, 65536, size=(6, 10, 3)).astype(np.uint16)
    base[0, 0] = (65535, 32768, 0)  # the int16 carriage must give these back
    if kind == "uint16":
        image = base
    elif kind == "reversed-uint16":
        image = base[::-1]  # negative strides
    elif kind == "planar-float32":
        image = planar_frame(6, 10, 3)
        image[...] = base
    elif kind == "float64":
        image = base.astype(np.float64) / 7.0
    else:
        image = (base % 256).astype(np.uint8)
    be = ArrayBackend("torch", "float32", device=device)
    planes = np.moveaxis(image, -1, 0)
    got = be._device_planes(image, planes, torch.float32)
    assert str(got.device).startswith(device) and got.dtype == torch.float32
    assert got.is_contiguous() and tuple(got.shape) == (3, 6, 10)
    np.testing.assert_array_equal(got.cpu().numpy(), planes.astype(np.float32))


@pytest.mark.parametrize("device", DEVICES)
def test_accelerator_split_reports_each_part(device: str) -> None:
    from thintact_sdk.apps.benchmarks.accelerator_split import accelerator_split
    from thintact_sdk.reconstruction.decoders import ArrayBackend, T2SClosedFormDecoder
    from thintact_sdk.reconstruction.synthetic_matrices import frequency_split_matrices

    sm, _ = frequency_split_matrices((64, 72), (20, 24), (8, 9), seed=1)
    x = np.random.default_rng(0).random((20, 24, 3)).astype(np.float32)
    raw = np.round(sm.forward(x) + 64.0).astype(np.uint16)
    dec = T2SClosedFormDecoder(sm, 1e-3, ArrayBackend("torch", "float32", device=device))
    out = accelerator_split(dec, raw, 64.0, repeats=2)
    assert out["device"].startswith(device) and out["input"] == "uint16 64x72x3"
    for k in ("upload_ms", "solve_ms", "download_ms", "gemm_gflops"):
        assert out[k] > 0 and np.isfinite(out[k]), k
    assert 0 <= out["device_ms"] <= out["solve_ms"]
