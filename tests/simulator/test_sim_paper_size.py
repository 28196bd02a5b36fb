"""The simulator at the paper's device size (issue 17): every effect either simulates or
refuses at once with a ThinTactError (the rotated mask and refraction, whose tabulated
families do not fit), never a MemoryError after minutes. The full 12-frame timing of every
effect is the slow test ``tests/diagnose/test_diagnose_paper_size.py``."""

from __future__ import annotations

import time

import numpy as np
import pytest

from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.simulation.simulator import Simulator, clear_kernel_cache


@pytest.mark.parametrize("physics, match", [
    ({"refraction": {"n_scene_side": 1.41}}, "refraction on this device"),
    ({"mask_misalignment": {"angle_deg": 0.3, "dx_um": 4.0, "dy_um": -3.0}}, "rotated by 0.3"),
], ids=["refraction", "rotation"])
def test_paper_size_families_refuse_at_once(physics: dict, match: str) -> None:
    sim = Simulator(load_profile("thintact-paper").with_physics(physics))
    t0 = time.perf_counter()
    with pytest.raises(ThinTactError, match=match):
        _ = sim.kernel
    assert time.perf_counter() - t0 < 20.0


def test_quarter_paper_device_simulates_shift_and_leakage() -> None:
    """A quarter of the paper's device (256×320 → 100×128, same pitches, mask and
    geometry): shifted and leaky masks go through the plain separable kernel and change
    the prediction by the expected sign."""
    base = load_profile("thintact-paper")
    d = base.contract_dict()
    d["sensor"]["rows"], d["sensor"]["cols"] = 256, 320
    d["scene"]["rows"], d["scene"]["cols"] = 100, 128
    from thintact_sdk.formats.profiles import profile_from_dict

    prof = profile_from_dict(d)
    x = np.random.default_rng(0).random((2, 100, 128, 3))
    clear_kernel_cache()
    y0 = Simulator(prof).forward_batch(x)
    shifted = Simulator(prof.with_physics(
        {"mask_misalignment": {"angle_deg": 0.0, "dx_um": 6.0, "dy_um": 0.0}})).forward_batch(x)
    leaky = Simulator(prof.with_physics({"mask_leakage": {"transmittance": 0.03}})).forward_batch(x)
    clear_kernel_cache()
    assert np.all(np.isfinite(shifted)) and np.all(np.isfinite(leaky))
    rel_shift = np.sqrt(np.mean((shifted - y0) ** 2) / np.mean(y0**2))
    assert 1e-3 < rel_shift < 0.5
    assert leaky.mean() > y0.mean()  # closed cells pass light: more signal everywhere
