"""Fast separable path against direct 4-D quadrature on tiny devices."""

from __future__ import annotations

import numpy as np
import pytest

from tests.simulator.sim_helpers import rel_rms, tiny_profile
from thintact_sdk.simulation.reference import reference_forward
from thintact_sdk.simulation.simulator import Simulator


@pytest.mark.parametrize("physics", [
    {},
    {"mask_leakage": {"transmittance": 0.1}},
    {"pixel_angular_response": {"exponent": 2.0}},
    {"mask_misalignment": {"dx_um": 37.0, "dy_um": -20.0}},
    {"geometry": {"scene_to_mask_mm": 2.3, "mask_to_sensor_mm": 0.45}},
])
def test_separable_matches_brute_force(physics):
    prof = tiny_profile(physics)
    sim = Simulator(prof)
    assert sim.separable
    x = np.random.default_rng(3).random((4, 5, 3))
    ref = reference_forward(prof, x, 12, 12)
    assert rel_rms(sim.forward(x), ref) < 2e-3


def test_brute_force_converges_towards_fast_path():
    prof = tiny_profile()
    x = np.random.default_rng(4).random((4, 5, 3))
    y = Simulator(prof).forward(x)
    e6 = rel_rms(y, reference_forward(prof, x, 6, 6))
    e12 = rel_rms(y, reference_forward(prof, x, 12, 12))
    assert e12 < e6 / 2


def test_separable_terms_reproduce_forward():
    prof = tiny_profile()
    sim = Simulator(prof)
    x = np.random.default_rng(5).random((4, 5, 3))
    y = sim.forward(x)
    for c in range(3):
        terms = sim.separable_terms(c)
        assert np.allclose(sum(p @ x[..., c] @ q.T for p, q in terms), y[..., c], rtol=1e-12)
        o, k = sim.open_coding_terms(c)
        half_open = sum(p @ x[..., c] @ q.T for p, q in o)
        assert np.allclose(half_open + sum(p @ x[..., c] @ q.T for p, q in k), y[..., c])


def test_open_half_is_half_the_open_aperture():
    """T = 1/2 everywhere inside the mask ⇔ the open terms; all-open φ doubles them."""
    prof = tiny_profile()
    allopen = prof.model_copy(deep=True)
    allopen.mask.phi = [1] * prof.mask.K
    allopen.mask.phi_rows = [1] * prof.mask.K
    x = np.random.default_rng(6).random((4, 5, 3))
    o, _ = Simulator(prof).open_coding_terms(0)
    y_open = sum(p @ x[..., 0] @ q.T for p, q in o)
    assert np.allclose(2 * y_open, Simulator(allopen).forward(x)[..., 0], rtol=1e-10)


def test_scene_shape_is_checked():
    from thintact_sdk.errors import ThinTactError

    with pytest.raises(ThinTactError, match="scenes must be"):
        Simulator(tiny_profile()).forward(np.zeros((5, 5, 3)))
