"""Decoding on the sensor binned 2 × 2: the same objective on half the products, offered to
the backend selection only as a measured, accuracy-checked candidate."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from thintact_sdk.algorithms import SystemMatrices
from thintact_sdk.device.sensor import Sensor
from thintact_sdk.errors import InvalidShapeError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.host.machine import HostCapabilities
from thintact_sdk.interfaces import Decoder
from thintact_sdk.pixels.bayer import planar_frame
from thintact_sdk.reconstruction.decoders import ArrayBackend, T2SClosedFormDecoder
from thintact_sdk.reconstruction.decoders.backend_cache import BackendCache
from thintact_sdk.reconstruction.decoders.backend_candidates import (
    candidate_specs,
    parse_preference,
)
from thintact_sdk.reconstruction.decoders.backend_selection import make_probes, select_backend
from thintact_sdk.reconstruction.decoders.sensor_binning import (
    SensorBinnedDecoder,
    bin_frame,
    bin_system_matrices,
    binning_possible,
)

HOST = HostCapabilities("Test CPU", 2, "AVX2", False, "openblas (2 threads)", "2.13.0+cpu, 2 threads", (),
                        ("avx2", "fma"))


def _operator(r: int = 48, s: int = 56, n: int = 20, m: int = 24, c: int = 3, seed: int = 0) -> SystemMatrices:
    """A small T2S operator like a lensless one: a smooth open term and a coding term that
    reads a random ±1 mask whose cells span 3 sensor pixels, along the stripes
    ``m = 0.8·r + 0.3·n`` (pixels)."""
    rng = np.random.default_rng(seed)

    def axis(rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
        a = np.linspace(-1, 1, rows)[:, None] - np.linspace(-1, 1, cols)[None]
        po = np.exp(-4 * a**2)
        cell = np.floor((0.8 * np.arange(rows)[:, None] + 0.3 * np.arange(cols)[None]) / 3.0).astype(int)
        phi = rng.choice([-1.0, 1.0], int(cell.max()) + 1)
        return po, 0.5 * po * phi[cell]

    po, pc = axis(r, n)
    qo, qc = axis(s, m)
    stack = lambda a: np.repeat(a[None], c, 0) * 2.0  # noqa: E731
    return SystemMatrices(stack(po), stack(qo), stack(pc), stack(qc))


def test_binned_operator_is_the_binned_measurement_exactly() -> None:
    sm = _operator()
    x = np.random.default_rng(1).random((20, 24, 3))
    y = sm.forward(x)
    yb = bin_frame(y.astype(np.float32))
    assert yb.shape == (24, 28, 3)
    np.testing.assert_allclose(yb, bin_system_matrices(sm).forward(x), rtol=1e-5)
    # the frame path: block means, black level removed, into a reused planar buffer
    out = planar_frame(24, 28, 3)
    raw = (y + 64.0).astype(np.float32)
    assert bin_frame(raw, 2, out, 64.0) is out
    np.testing.assert_allclose(out, yb, rtol=1e-5, atol=1e-4)


def test_odd_sensor_is_refused_and_undersampled_sensor_not_offered() -> None:
    with pytest.raises(InvalidShapeError, match="multiples of 2"):
        bin_system_matrices(_operator(r=47))
    assert binning_possible((48, 56), (20, 24))
    assert not binning_possible((48, 56), (25, 24))  # 24 binned rows < 25 scene rows
    assert not binning_possible((47, 56), (20, 24))


def test_wrapper_speaks_the_unbinned_tau_and_decodes_like_its_inner_solve() -> None:
    sm = _operator()
    tau = 50.0
    inner = T2SClosedFormDecoder(bin_system_matrices(sm), tau / 4, ArrayBackend("numpy", "float64"))
    dec = SensorBinnedDecoder(inner, sm.sensor_shape, sm.channels)
    assert dec.tau == pytest.approx(tau)
    x = np.random.default_rng(2).random((20, 24, 3))
    y = sm.forward(x)
    np.testing.assert_allclose(dec.decode(y), inner.decode(bin_frame(y.astype(np.float32))), atol=1e-5)
    np.testing.assert_allclose(dec.decode((y + 10.0).astype(np.float32), 10.0), dec.decode(y), atol=1e-4)
    dec.set_tau(8 * tau)
    assert inner.tau == pytest.approx(2 * tau) and dec.tau == pytest.approx(8 * tau)
    assert dec.info["sensor_bin"] == 2 and dec.gemm_flops() == inner.gemm_flops()
    with pytest.raises(InvalidShapeError):
        dec.decode(y[:-2])


def test_binning_is_free_only_where_the_noise_hides_the_pixel_scale_detail() -> None:
    """The same objective (τ / 4) on a sensor that oversamples the scene 2.4 ×: at a noise
    level where the best τ smooths below two pixels, the binned reconstruction is within 0.2 dB
    of the unbinned float64 one at every τ of the grid; at low noise it loses over 1 dB at the
    best τ. Hence a measured candidate, never a default."""
    from scipy.ndimage import gaussian_filter

    from thintact_sdk.algorithms import psnr

    sm = _operator()
    rng = np.random.default_rng(3)
    x = gaussian_filter(rng.random((20, 24, 3)), (1.5, 1.5, 0))
    x = (x - x.min()) / np.ptp(x)
    full = T2SClosedFormDecoder(sm, 1.0, ArrayBackend("numpy", "float64"))
    binned = T2SClosedFormDecoder(bin_system_matrices(sm), 1.0, ArrayBackend("numpy", "float64"))

    def table(sigma: float) -> np.ndarray:
        y = sm.forward(x) + rng.normal(0, sigma, (48, 56, 3))
        yb = bin_frame(y.astype(np.float32))
        rows = []
        for t in (1e2, 3e2, 1e3, 3e3, 1e4):
            full.set_tau(t)
            binned.set_tau(t / 4)
            rows.append([psnr(np.clip(full.decode(y), 0, 1), x), psnr(np.clip(binned.decode(yb), 0, 1), x)])
        return np.array(rows)

    noisy, clean = table(20.0), table(0.5)
    assert np.max(noisy[:, 0] - noisy[:, 1]) < 0.2
    assert noisy[:, 0].max() > 17.0
    assert clean[:, 0].max() - clean[:, 1].max() > 1.0


def test_binned_candidates_keys_and_preferences() -> None:
    keys = [s.key for s in candidate_specs(HOST, "float32", torch_available=True, sensor_bin=2)]
    assert keys == ["numpy-float32", "torch-float32", "numpy-float32-bin2", "torch-float32-bin2"]
    assert [s.key for s in candidate_specs(HOST, "float32", torch_available=True)] == keys[:2]
    spec = parse_preference("numpy-float32-bin2")
    assert spec.sensor_bin == 2 and spec.key == "numpy-float32-bin2"
    assert parse_preference("torch").sensor_bin == 1
    with pytest.raises(ValueError, match="-bin<k>"):
        parse_preference("numpy-float32-binx")


def test_selection_builds_binned_candidates_and_scores_them_against_the_unbinned_float64(tmp_path) -> None:
    sm = _operator()
    probes = make_probes(sm, load_profile("virtual-mini").noise)
    calls: list[int] = []

    def build(xp: ArrayBackend, b: int = 1) -> object:
        calls.append(b)
        if b == 1:
            return T2SClosedFormDecoder(sm, 200.0, xp)
        return SensorBinnedDecoder(T2SClosedFormDecoder(bin_system_matrices(sm, b), 50.0, xp),
                                   sm.sensor_shape, sm.channels, b)

    specs = candidate_specs(HOST, "float32", torch_available=False, sensor_bin=2)
    decoder, choice = select_backend(build, lambda: probes, specs, "test|t2s|bin",
                                     cache=BackendCache(tmp_path / "b.json"))
    assert calls[0] == 1  # the float64 reference is the unbinned solve
    assert 2 in calls
    assert set(choice.measured_ms) == {"numpy-float32", "numpy-float32-bin2"}
    assert np.isfinite(choice.psnr_cost_db["numpy-float32-bin2"])
    assert isinstance(decoder, SensorBinnedDecoder) == (choice.chosen == "numpy-float32-bin2")


def test_concurrent_decode_workers_do_not_share_the_binned_frame() -> None:
    sm = _operator()
    dec = SensorBinnedDecoder(T2SClosedFormDecoder(bin_system_matrices(sm), 50.0), sm.sensor_shape, sm.channels)
    rng = np.random.default_rng(4)
    frames = [sm.forward(rng.random((20, 24, 3))).astype(np.float32) for _ in range(4)]
    serial = [dec.decode(f) for f in frames]
    results: dict[int, list[np.ndarray]] = {}

    def work(i: int) -> None:
        results[i] = [dec.decode(frames[(i + k) % 4]) for k in range(12)]

    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for i, outs in results.items():
        for k, out in enumerate(outs):
            np.testing.assert_allclose(out, serial[(i + k) % 4], atol=1e-5)


def test_binning_is_offered_by_default_only_where_the_products_are_heavy() -> None:
    from thintact_sdk.reconstruction.decoders.sensor_binning import binning_offered

    assert binning_offered((1024, 1280), (400, 512), 3) == 2  # the paper device: 3.1 GFLOP first product
    assert binning_offered((256, 320), (100, 128), 3) == 1  # the virtual finger: 0.05 GFLOP
    assert binning_offered((256, 320), (100, 128), 3, 2) == 2
    assert binning_offered((1024, 1280), (400, 512), 3, 1) == 1
    assert binning_offered((1024, 1280), (600, 512), 3, 2) == 1  # 512 binned rows < 600 scene rows
    with pytest.raises(ValueError, match="sensor_bin"):
        binning_offered((1024, 1280), (400, 512), 3, "yes")


def test_the_registry_offers_the_binned_solve_when_the_setting_asks(tmp_path, monkeypatch) -> None:
    from thintact_sdk.device.registry import get_registry
    from thintact_sdk.errors import CalibrationError

    monkeypatch.setenv("THINTACT_CACHE_DIR", str(tmp_path))
    profile = load_profile("virtual-mini")
    reg = get_registry()
    dec = reg.create("decoder", "t2s-closed-form", profile, {"sensor_bin": 2})
    assert set(dec.backend_choice.measured_ms) >= {"numpy-float32", "numpy-float32-bin2"}
    plain = reg.create("decoder", "t2s-closed-form", profile, {})
    assert not any(k.endswith("-bin2") for k in plain.backend_choice.measured_ms)
    assert dec.tau == pytest.approx(plain.tau)  # the unbinned τ either way
    with pytest.raises(CalibrationError, match="sensor_bin"):
        reg.create("decoder", "t2s-closed-form", profile, {"sensor_bin": 3})


def _mini_sensor(decoder: Decoder) -> Sensor:
    return Sensor(load_profile("virtual-mini"), decoder=decoder)


@pytest.mark.parametrize("pixel_format", ["BayerRG12", "BayerGB12"])
def test_sensor_bins_the_mosaic_once_for_a_binned_decoder(pixel_format: str) -> None:
    """Raw Bayer → the binned decoder's input in one pass (``sensor_bin = 2``: 4 × 4 cells of
    the mosaic per colour site) decodes to the same scene, to float32 rounding, as binning
    2 × 2 into the measurement and letting the decoder bin it again; black level included."""
    from thintact_sdk.device.cameras import to_measurement
    from thintact_sdk.device.sensor import _InFlight
    from thintact_sdk.frames import RawFrame
    from thintact_sdk.interfaces import DecoderInput
    from thintact_sdk.pixels.bayer import mosaic_from_rgb
    from thintact_sdk.reconstruction.decoders.sensor_binning import binnable_build

    profile = load_profile("virtual-mini")  # 128 × 160 sensor, 50 × 64 scene, black 64 DN
    sm = _operator(128, 160, 50, 64)
    build = binnable_build(sm, 40.0, lambda s, t, xp: T2SClosedFormDecoder(s, t, xp))
    dec = build(ArrayBackend("numpy", "float32"), 2)
    assert DecoderInput.of(dec) == DecoderInput("binned", 2)
    x = np.random.default_rng(4).random((50, 64, 3))
    pattern = {"BayerRG12": "RGGB", "BayerGB12": "GBRG"}[pixel_format]
    mosaic = mosaic_from_rgb(sm.forward(x) * 300.0 + 64.0, pattern)  # per-site noise: the two G differ
    mosaic = np.clip(np.round(mosaic + np.random.default_rng(5).normal(0, 3, mosaic.shape)), 0, 4095)
    raw = RawFrame(mosaic.astype(np.uint16), 0, 7, pixel_format)
    sensor = _mini_sensor(dec)
    m = sensor.decoder_input(raw)  # what the stream's bin stage makes
    assert m.sensor_bin == 2 and m.data.shape == (64, 80, 3) and m.frame_id == 7 and m.black_level_dn == 64.0
    # the binned measurement is exactly the block means of the 2 × 2-binned one
    np.testing.assert_array_equal(m.data, bin_frame(to_measurement(raw, profile).data))
    one_pass = sensor.reconstruct(m)
    two_pass = sensor.reconstruct(to_measurement(raw, profile))
    assert one_pass.shape == (50, 64, 3)
    scale = float(np.abs(two_pass).max())
    np.testing.assert_allclose(one_pass, two_pass, rtol=0, atol=1e-5 * scale)
    # the stream's stages take the same path
    item = _InFlight(raw, 0)
    sensor._bin_stage(item)
    sensor._decode_stage(item)
    np.testing.assert_array_equal(item.image, one_pass)


def test_a_decoder_without_the_capability_gets_the_full_measurement() -> None:
    from thintact_sdk.device.cameras import to_measurement
    from thintact_sdk.device.sensor import _InFlight
    from thintact_sdk.errors import InvalidValueError
    from thintact_sdk.frames import RawFrame
    from thintact_sdk.interfaces import DecoderInput

    profile = load_profile("virtual-mini")
    dec = T2SClosedFormDecoder(_operator(128, 160, 50, 64), 40.0, ArrayBackend("numpy", "float32"))
    assert DecoderInput.of(dec) == DecoderInput("raw", 1)
    raw = RawFrame(np.random.default_rng(6).integers(64, 4000, (256, 320)).astype(np.uint16), 0, 3, "BayerRG12")
    sensor = _mini_sensor(dec)
    m, full = sensor.decoder_input(raw), to_measurement(raw, profile)
    assert m.sensor_bin == 1
    np.testing.assert_array_equal(m.data, full.data)
    item = _InFlight(raw, 0)
    sensor._bin_stage(item)
    sensor._decode_stage(item)
    np.testing.assert_array_equal(item.image, dec.decode(full.data, 64.0))
    # a measurement binned for another decoder is refused, never decoded as if it were whole
    with pytest.raises(InvalidValueError, match="frame 3 was binned 2×2"):
        sensor.reconstruct(to_measurement(raw, profile, sensor_bin=2))
    with pytest.raises(InvalidValueError, match="sensor_bin 3"):
        to_measurement(raw, profile, sensor_bin=3)


def test_backends_are_judged_at_the_probes_best_tau_whatever_tau_they_are_built_with() -> None:
    # at an unregularised τ every backend decodes noise alike, so a lossy one (binned) looked
    # free; the calibration builds its decoders at whatever τ it has at hand (issue 36)
    from thintact_sdk.reconstruction.decoders.backend_selection import measure_backends, probe_tau
    from thintact_sdk.reconstruction.decoders.modes import channel_taus

    sm = _operator()
    probes = make_probes(sm, load_profile("virtual-mini").noise)
    specs = candidate_specs(HOST, "float32", torch_available=False, sensor_bin=2)

    def builder(tau: float):  # type: ignore[no-untyped-def]
        def build(xp: ArrayBackend, b: int = 1) -> Decoder:
            if b == 1:
                return T2SClosedFormDecoder(sm, tau, xp)
            inner = T2SClosedFormDecoder(bin_system_matrices(sm, b), channel_taus(tau, sm.channels) / b**2, xp)
            return SensorBinnedDecoder(inner, sm.sensor_shape, sm.channels, b)
        return build

    best = probe_tau(builder(200.0)(ArrayBackend("numpy", "float64")), probes)
    assert best is not None
    costs = {}
    for tau in (1e-3, 200.0, 1e5):
        _, cost, failed, decoders = measure_backends(builder(tau), probes, specs, repeats=1)
        assert not failed
        for dec in decoders.values():  # handed back at the τ they were built with
            np.testing.assert_allclose(dec.channel_tau, tau, rtol=1e-9)  # type: ignore[attr-defined]
        costs[tau] = cost
    for tau in (1e-3, 1e5):  # the same verdict from every starting τ (the search grid is absolute)
        for key in costs[200.0]:
            assert abs(costs[tau][key] - costs[200.0][key]) < 0.02, (tau, key, costs)
    # and the τ found is the best of a fine sweep on the float64 reference, within its quarter decade
    ref = builder(200.0)(ArrayBackend("numpy", "float64"))
    sweep = {t: np.mean([float(-10 * np.log10(np.mean((np.clip(_decode(ref, t, p), 0, 1) - p.truth) ** 2)))
                         for p in probes]) for t in best * np.logspace(-1, 1, 41)}
    assert abs(np.log10(max(sweep, key=sweep.__getitem__) / best)) <= 0.25


def _decode(decoder: Decoder, tau: float, probe) -> np.ndarray:  # type: ignore[no-untyped-def]
    decoder.set_tau(tau)  # type: ignore[attr-defined]
    return decoder.decode(probe.raw.astype(np.float32) - np.float32(probe.black_dn))


def test_a_float64_candidate_is_the_reference_itself_not_built_or_scored_again() -> None:
    from thintact_sdk.reconstruction.decoders.backend_candidates import BackendSpec
    from thintact_sdk.reconstruction.decoders.backend_selection import measure_backends

    sm = _operator()
    probes = make_probes(sm, load_profile("virtual-mini").noise)
    built: list[str] = []

    def build(xp: ArrayBackend) -> Decoder:
        built.append(repr(xp))
        return T2SClosedFormDecoder(sm, 200.0, xp)

    specs = [BackendSpec("numpy", dtype="float64", gemm_dtype="float64"),
             BackendSpec("numpy", dtype="float32")]
    measured, cost, failed, decoders = measure_backends(build, probes, specs, repeats=1)
    assert not failed and set(measured) == {s.key for s in specs}
    assert len(built) == 2  # the reference and the float32 candidate, nothing twice
    assert cost[specs[0].key] == 0.0 and cost[specs[1].key] < 0.1
    assert decoders[specs[0].key].channel_tau == pytest.approx(200.0)  # type: ignore[attr-defined]
