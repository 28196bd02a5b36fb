"""Decoders: exact recovery on noiseless synthetic T2S data, backends, plugin registry loading."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.device.registry import get_registry
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import load_profile, profile_from_dict
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.decoders import (
    ArrayBackend,
    FlatCamDecoder,
    NonIterativeDecoder,
    T2SIterativeDecoder,
)
from thintact_sdk.reconstruction.synthetic_matrices import frequency_split_matrices
from thintact_sdk.reconstruction.t2s import SystemMatrices

SENSOR, SCENE, BLOCK = (64, 72), (20, 24), (8, 9)


@pytest.fixture(scope="module")
def synthetic():
    sm, jf = frequency_split_matrices(SENSOR, SCENE, BLOCK, seed=1)
    x = np.random.default_rng(0).random((*SCENE, 3)).astype(np.float32)
    return sm, jf, x, sm.forward(x).astype(np.float32)


BACKENDS = [("numpy", "float32"), ("numpy", "float64"), ("torch", "float32")]


@pytest.mark.parametrize("backend,dtype", BACKENDS)
@pytest.mark.parametrize("fold", ["auto", "never"])
def test_noniterative_exact_recovery(synthetic, backend, dtype, fold) -> None:
    sm, jf, x, y = synthetic
    dec = NonIterativeDecoder(sm, jf, 1e-9, ArrayBackend(backend, dtype), fold=fold)
    assert dec.folded == (fold == "auto")
    xh = dec.decode(y)
    assert xh.shape == x.shape and xh.dtype == np.float32
    assert np.abs(xh - x).max() < 1e-4
    # raw DN with the black level folded into the solve
    np.testing.assert_allclose(dec.decode(y + 64.0, 64.0), x, atol=1e-4)


def test_noniterative_bfloat16_gemms_stay_close(synthetic) -> None:
    sm, jf, x, y = synthetic
    dec = NonIterativeDecoder(sm, jf, 1e-9, ArrayBackend("torch", gemm_dtype="bfloat16"))
    err = np.abs(dec.decode(y) - x).max()
    assert 0 < err < 0.05


@pytest.mark.parametrize("backend", ["numpy", "torch"])
def test_iterative_converges_to_the_scene(synthetic, backend) -> None:
    sm, _, x, y = synthetic
    dec = T2SIterativeDecoder(sm, 1e-9, iterations=800, backend=ArrayBackend(backend))
    assert np.abs(dec.decode(y) - x).max() < 2e-3
    few = T2SIterativeDecoder(sm, 1e-9, iterations=5, backend=ArrayBackend(backend))
    assert np.abs(few.decode(y) - x).max() > 10 * np.abs(dec.decode(y) - x).max()


def test_iterative_gram_form_matches_forward_adjoint(synthetic) -> None:
    sm, _, x, _ = synthetic
    dec = T2SIterativeDecoder(sm, 0.0, iterations=1, backend=ArrayBackend("numpy", "float64"))
    xc = np.moveaxis(x, -1, 0).astype(np.float64)
    direct = dec.adjoint(np.moveaxis(sm.forward(x), -1, 0))
    np.testing.assert_allclose(dec._gram(xc), direct, rtol=1e-9, atol=1e-9 * np.abs(direct).max())


def test_flatcam_exact_when_open_part_is_row_constant() -> None:
    rng = np.random.default_rng(2)
    r, s, n, m = 64, 72, 20, 24
    po = np.ones((3, r, 1)) * rng.random((3, 1, n))  # Po X Qoᵀ = 1 bᵀ: removed by centring
    sm = SystemMatrices(po, rng.random((3, s, m)), rng.standard_normal((3, r, n)),
                        rng.standard_normal((3, s, m)))
    x = rng.random((n, m, 3)).astype(np.float32)
    y = sm.forward(x).astype(np.float32)
    np.testing.assert_allclose(FlatCamDecoder(sm, 1e-9).decode(y), x, atol=1e-4)
    np.testing.assert_allclose(FlatCamDecoder(sm, 1e-9, ArrayBackend("torch")).decode(y), x, atol=1e-4)


def test_wrong_measurement_shape_is_refused(synthetic) -> None:
    sm, jf, _, _ = synthetic
    with pytest.raises(ValueError, match="measurement must be"):
        NonIterativeDecoder(sm, jf, 1e-3).decode(np.zeros((10, 10, 3), np.float32))


def _small_profile(tmp_path, calibration: str | None):
    d = load_profile("virtual-mini").contract_dict()
    d["name"] = "rec-test-small"
    d["sensor"].update(rows=SENSOR[0], cols=SENSOR[1])
    d["scene"].update(rows=SCENE[0], cols=SCENE[1])
    d["decoder"] = {"plugin": "thintact-noniterative", "settings": {"tau": 1e-9}}
    if calibration:
        d["decoder"]["calibration"] = calibration
    return profile_from_dict(d)


def test_decoders_load_through_the_plugin_registry(synthetic, tmp_path) -> None:
    sm, jf, x, y = synthetic
    profile = _small_profile(tmp_path, None)
    bundle_dir = CalibrationBundle.create(profile, sm, jf, tau=1e-9, source="simulator").save(
        tmp_path / "bundle"
    )
    reg = get_registry()
    assert {"thintact-noniterative", "t2s-iterative", "flatcam"} <= set(reg.components("decoder"))
    assert reg.get("decoder", "flatcam").plugin == "thintact-sdk"
    dec = reg.create("decoder", "thintact-noniterative", profile, {"calibration": str(bundle_dir)})
    np.testing.assert_allclose(dec.decode(y), x, atol=1e-4)
    it = reg.create("decoder", "t2s-iterative", profile,
                    {"calibration": str(bundle_dir), "iterations": 800})
    assert np.abs(it.decode(y) - x).max() < 2e-3
    via_profile = _small_profile(tmp_path, str(bundle_dir))
    assert reg.create("decoder", "flatcam", via_profile, {}).decode(y).shape == x.shape
    with pytest.raises(CalibrationError, match="no calibration bundle for virtual profile"):
        reg.create("decoder", "flatcam", profile, {})
    with pytest.raises(CalibrationError, match="sensor"):
        reg.create("decoder", "flatcam", load_profile("virtual-finger"), {"calibration": str(bundle_dir)})


def test_iterative_direct_gradient_gives_the_same_iterates(synthetic) -> None:
    sm, _, _, y = synthetic
    be = ArrayBackend("numpy", "float64")
    gram = T2SIterativeDecoder(sm, 1e-3, iterations=30, backend=be).decode(y)
    direct = T2SIterativeDecoder(sm, 1e-3, iterations=30, backend=be, gradient="direct").decode(y)
    np.testing.assert_allclose(direct, gram, atol=1e-5 * np.abs(gram).max())
    with pytest.raises(ValueError, match="gradient"):
        T2SIterativeDecoder(sm, 1e-3, gradient="fast")


@pytest.mark.parametrize("src", ["uint16", "uint8", "float32", "float64", "uint16-strided", "uint16-reversed"])
@pytest.mark.parametrize("gemm", ["float32", "bfloat16"])
def test_torch_channels_first_one_pass_equals_the_numpy_conversion(src: str, gemm: str) -> None:
    """The torch CPU fast path (permuted copy straight into the GEMM precision) gives exactly
    what converting through a float32 channel-first buffer gives, for camera DN and floats,
    strided and reversed views included."""
    import torch

    rng = np.random.default_rng(3)
    base = rng.integers(0, 4096, (18, 22, 3))
    dtype = src.split("-")[0]
    image = base.astype(dtype) if "float" not in dtype else (base / 4096.0).astype(dtype)
    if src.endswith("strided"):
        image = image[::2, 1::2]
    elif src.endswith("reversed"):
        image = image[::-1]
    xp = ArrayBackend("torch", "float32", device="cpu", gemm_dtype=gemm)
    got = xp.channels_first(image, gemm=True)
    want = torch.from_numpy(np.moveaxis(image.astype(np.float32), -1, 0).copy()).to(getattr(torch, gemm))
    assert got.dtype == want.dtype and got.is_contiguous()
    assert torch.equal(got, want)
