"""Kernels of sensor windows (:mod:`thintact_sdk.simulation.tiled`): a window's kernel is the
whole device's on the window's pixels, and a rotated mask built window by window gives the
whole build's frames (the whole build is checked against the brute force in
``test_sim_rotated.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.simulator.sim_helpers import rel_rms
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.simulation import rotated as sim_rotated
from thintact_sdk.simulation import tiled as sim_tiled
from thintact_sdk.simulation.effects import resolve_physics
from thintact_sdk.simulation.params import kernel_params
from thintact_sdk.simulation.simulator import Simulator, build_separable_kernel, clear_kernel_cache
from thintact_sdk.simulation.tiled import TiledKernel, plan_windows, split_axis, window_params


def _scenes(n: int = 2) -> np.ndarray:
    return np.random.default_rng(5).random((n, 50, 64, 3))


def _kp(physics: dict) -> object:
    prof = load_profile("virtual-mini").with_physics(physics)
    return kernel_params(prof, resolve_physics(prof.physics))


def _rank(kp: object) -> int:
    from thintact_sdk.simulation.simulator import _expansion

    return int(_expansion(kp).rank)  # type: ignore[arg-type]


def test_split_axis_covers_every_pixel_once():
    for n, parts in ((128, 3), (160, 7), (5, 5)):
        spans = split_axis(n, parts)
        assert spans[0][0] == 0 and spans[-1][1] == n
        assert all(a[1] == b[0] for a, b in zip(spans, spans[1:], strict=False))
        assert max(b - a for a, b in spans) - min(b - a for a, b in spans) <= 1


@pytest.mark.parametrize("physics", [{}, {"mask_misalignment": {"dx_um": 4.0, "dy_um": -3.0}},
                                     {"pixel_angular_response": {"exponent": 3.0}}])
def test_window_kernel_is_the_whole_kernel_on_its_pixels(physics):
    """An off-axis window of the plain separable kernel: the same numbers as the whole
    device's rows and columns there to the radiometric expansion's and the term compression's
    cuts (the sensor offset enters the geometry exactly)."""
    kp = _kp(physics)
    x = _scenes()
    whole = build_separable_kernel(kp).apply(x)
    for r0, r1, c0, c1 in ((0, 40, 0, 50), (90, 128, 101, 160), (33, 70, 7, 121)):
        win = build_separable_kernel(window_params(kp, r0, r1, c0, c1)).apply(x)
        assert rel_rms(win, whole[:, r0:r1, c0:c1]) < 1e-6  # expansion and compression cuts: 1e-7, 1e-5


@pytest.mark.parametrize("physics", [
    {"mask_misalignment": {"angle_deg": 0.35}},
    {"mask_misalignment": {"angle_deg": -0.8, "dx_um": 5.0}},
    {"mask_misalignment": {"angle_deg": 0.35}, "diffraction": {"wavelength_nm": [600.0, 600.0, 600.0]}},
])
def test_rotated_mask_in_windows_matches_the_whole_build(physics):
    """2 × 3 windows against one whole-sensor build: the same frames to a few 1e-5 (each
    build compresses its own displacement family; the contract allows 1e-3)."""
    kp = _kp(physics)
    x = _scenes()
    whole = build_separable_kernel(kp).apply(x)
    spans = [(r0, r1, c0, c1) for r0, r1 in split_axis(kp.rows, 2) for c0, c1 in split_axis(kp.cols, 3)]
    exp_info: dict[str, float] = {}
    from thintact_sdk.simulation import simulator as simmod

    exp = simmod._expansion(kp)
    tiled = sim_tiled.build_tiled_kernel(kp, spans, lambda w: simmod._build_rotated_window(w, exp, dict(exp_info)))
    assert isinstance(tiled, TiledKernel) and tiled.info["windows"] == 6
    assert rel_rms(tiled.apply(x), whole) < 1e-4
    assert rel_rms(tiled.apply(x, "float32"), whole) < 1e-4


def test_windows_have_smaller_families_and_plan_meets_the_limit():
    kp = _kp({"mask_misalignment": {"angle_deg": 0.35}})
    size = lambda w: sim_rotated.rotated_family_bytes(w, _rank(kp))  # noqa: E731
    whole = size(kp)
    spans = plan_windows(kp, size, window_limit=whole / 3)
    assert len(spans) > 1
    assert all(size(window_params(kp, *s)) <= whole / 3 for s in spans)
    covered = np.zeros((kp.rows, kp.cols), int)
    for r0, r1, c0, c1 in spans:
        covered[r0:r1, c0:c1] += 1
    assert np.all(covered == 1)


def test_plan_refuses_a_build_that_would_take_too_long():
    kp = _kp({"mask_misalignment": {"angle_deg": 0.35}})
    size = lambda w: sim_rotated.rotated_family_bytes(w, _rank(kp))  # noqa: E731
    with pytest.raises(ThinTactError, match="sensor windows .* bin the sensor"):
        plan_windows(kp, size, window_limit=size(kp) / 3, total_limit=size(kp) / 2)


def test_window_outside_the_sensor_is_refused():
    kp = _kp({})
    with pytest.raises(ThinTactError, match="not inside"):
        window_params(kp, 0, 129, 0, 10)


def test_simulator_tiles_a_device_whose_rotated_family_is_large(monkeypatch):
    """With the window limit lowered, the Simulator builds the rotated mask (with leakage,
    which rescales each window's halves) window by window: the same frames, and the
    separable terms are refused with the reason."""
    physics = {"mask_misalignment": {"angle_deg": 0.35}, "mask_leakage": {"transmittance": 0.03}}
    prof = load_profile("virtual-mini").with_physics(physics)
    x = _scenes(1)
    clear_kernel_cache()
    whole = Simulator(prof).forward_batch(x)
    assert not isinstance(Simulator(prof).kernel, TiledKernel)
    kp = _kp(physics)
    monkeypatch.setattr(sim_tiled, "WINDOW_FAMILY_BYTES", sim_rotated.rotated_family_bytes(kp, _rank(kp)) / 2.5)
    clear_kernel_cache()
    sim = Simulator(prof)
    assert isinstance(sim.kernel, TiledKernel) and sim.kernel.info["windows"] >= 2
    assert rel_rms(sim.forward_batch(x), whole) < 1e-4
    with pytest.raises(ThinTactError, match="window by window"):
        sim.open_coding_terms(0)
    clear_kernel_cache()


def test_refraction_and_direct_paths_refuse_a_window():
    from thintact_sdk.simulation.simulator import get_kernel

    kp = window_params(_kp({"refraction": {"n_scene_side": 1.4}}), 0, 10, 0, 10)
    with pytest.raises(ThinTactError, match="straight rays"):
        build_separable_kernel(kp)
    prof = load_profile("virtual-mini")
    kpd = window_params(kernel_params(prof, {}, force_direct=True), 0, 10, 0, 10)
    with pytest.raises(ThinTactError, match="separable path only"):
        get_kernel(kpd)


def test_streamed_windows_give_the_kept_windows_frames(monkeypatch):
    """``Simulator(stream_windows=True)`` builds each window at the forward call and drops it
    (for rendering a paper-size rotated recording, whose kept windows would not fit): the same
    windows, so the same frames as the kept tiled build, and nothing enters the kernel cache."""
    from thintact_sdk.simulation import simulator as simmod
    from thintact_sdk.simulation.tiled import StreamedTiledKernel

    physics = {"mask_misalignment": {"angle_deg": 0.35}, "mask_leakage": {"transmittance": 0.03}}
    prof = load_profile("virtual-mini").with_physics(physics)
    kp = _kp(physics)
    x = _scenes(1)
    monkeypatch.setattr(sim_tiled, "WINDOW_FAMILY_BYTES", sim_rotated.rotated_family_bytes(kp, _rank(kp)) / 2.5)
    clear_kernel_cache()
    kept = Simulator(prof).forward_batch(x)
    clear_kernel_cache()
    sim = Simulator(prof, stream_windows=True)
    done: list[tuple[int, int]] = []
    assert isinstance(sim.kernel, StreamedTiledKernel)
    sim.kernel.progress = lambda i, n: done.append((i, n))
    assert rel_rms(sim.forward_batch(x), kept) < 1e-9
    assert sim.kernel.info["windows"] >= 2 and done[-1][0] == done[-1][1] == sim.kernel.info["windows"]
    assert not simmod._KERNEL_CACHE
    # an unrotated device is never streamed
    assert not isinstance(Simulator(load_profile("virtual-mini"), stream_windows=True).kernel, StreamedTiledKernel)
    clear_kernel_cache()


def test_rotated_build_bytes_sums_the_windows_and_grows_with_the_angle():
    from thintact_sdk.simulation.simulator import rotated_build_bytes

    assert rotated_build_bytes(_kp({})) == 0.0
    small = rotated_build_bytes(_kp({"mask_misalignment": {"angle_deg": 0.1}}))
    large = rotated_build_bytes(_kp({"mask_misalignment": {"angle_deg": 0.35}}))
    assert 0.0 < small < large
    kp = _kp({"mask_misalignment": {"angle_deg": 0.35}})
    assert large == sim_rotated.rotated_family_bytes(kp, _rank(kp))  # under the window limit: one build


def test_a_window_refused_for_its_size_is_built_in_quadrants():
    """The planner bounds a window's displacement families, but its separable terms can still
    be refused (:class:`KernelSizeError`, e.g. a 114×116 window of the paper's sensor at 0.2°):
    the window is then built as its quadrants, recursively, covering it exactly and giving the
    same frames; a window still refused after the last split keeps the refusal."""
    from thintact_sdk.errors import KernelSizeError
    from thintact_sdk.simulation import simulator as simmod
    from thintact_sdk.simulation.tiled import MAX_SPLITS, build_window_pieces

    kp = _kp({"mask_misalignment": {"angle_deg": 0.35, "dx_um": 3.0}})
    exp = simmod._expansion(kp)
    x = _scenes()
    whole = build_separable_kernel(kp).apply(x)

    def build(w):  # windows above 40×40 pixels are "too large"
        if w.rows * w.cols > 1600:
            raise KernelSizeError(f"{w.rows}×{w.cols} too large")
        return simmod._build_rotated_window(w, exp, {})

    tiled = sim_tiled.build_tiled_kernel(kp, [(0, kp.rows, 0, 80), (0, kp.rows, 80, kp.cols)], build)
    assert all(w.kernel is not None and (w.row1 - w.row0) * (w.col1 - w.col0) <= 1600 for w in tiled.windows)
    covered = np.zeros((kp.rows, kp.cols), int)
    for w in tiled.windows:
        covered[w.row0:w.row1, w.col0:w.col1] += 1
    assert np.all(covered == 1) and tiled.info["windows"] == len(tiled.windows) == 32  # 128×80 → 64×40 → 32×20
    assert rel_rms(tiled.apply(x), whole) < 1e-4

    def never(w):
        raise KernelSizeError("always")

    with pytest.raises(KernelSizeError):
        build_window_pieces(kp, (0, 64, 0, 64), never)
    assert MAX_SPLITS == 3


@pytest.mark.parametrize("physics", [
    {"mask_misalignment": {"angle_deg": 0.35}},
    {"color_crosstalk": {"matrix": [[1, 0.04, 0.01], [0.03, 1, 0.03], [0.0, 0.05, 1]]},
     "display_gamma": {"gamma": 1.15}, "scene_blur": {"sigma_um": 40.0}},
])
def test_linear_window_is_the_whole_simulation_on_its_pixels(physics):
    """``Simulator.linear_window``: stages 1-3 on a window of the sensor only (scene-stage
    effects and pixel-local signal effects included) give those pixels of ``linear_batch``."""
    sim = Simulator(load_profile("virtual-mini").with_physics(physics))
    x = _scenes()
    whole = sim.linear_batch(x)
    for span in ((0, 40, 0, 50), (90, 128, 101, 160)):
        r0, r1, c0, c1 = span
        assert rel_rms(sim.linear_window(x, span), whole[:, r0:r1, c0:c1]) < 1e-5


@pytest.mark.parametrize(("physics", "words"), [
    ({"sensor_blur": {"sigma_um": 5.0}}, "sensor_blur gives each pixel light from its neighbouring pixels: a window"),
    ({"veiling_glare": {"fraction": 0.02}}, "veiling_glare gives each pixel a share of the whole frame's mean"),
    ({"refraction": {"n_scene_side": 1.4}}, "straight rays only"),
])
def test_linear_window_refuses_what_reads_beyond_the_window(physics, words):
    sim = Simulator(load_profile("virtual-mini").with_physics(physics))
    with pytest.raises(ThinTactError, match=words):
        sim.linear_window(_scenes(1), (0, 40, 0, 50))
