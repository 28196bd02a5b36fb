"""Issue 36: the speed-ups of a paper-size calibration change no figure.

The design prediction images its simulated slits from the simulator's separable expansion
(:func:`~thintact_sdk.calibration.prediction.slit_factors`) instead of a forward pass of each
slit scene; the two must agree to rounding.
"""

from __future__ import annotations

import numpy as np

from thintact_sdk.calibration.prediction import _slit_signal_dn, slit_factors
from thintact_sdk.imaging.simulator import Simulator
from thintact_sdk.profile import Profile, load_profile


def _slit_scenes(idx: list[int], n: int, m: int, c: int) -> np.ndarray:
    x = np.zeros((len(idx), n, m, c))
    for b, i in enumerate(idx):
        if i < n:
            x[b, i] = 1.0
        else:
            x[b, :, i - n] = 1.0
    return x


def test_slit_images_from_the_separable_expansion_equal_the_simulator() -> None:
    prof = load_profile("virtual-mini")
    sim = Simulator(prof)
    n, m = prof.scene.rows, prof.scene.cols
    factors = slit_factors(sim, 3)
    assert factors is not None
    idx = [0, 7, n - 1, n, n + 20, n + m - 1]
    gains = np.array([900.0, 800.0, 700.0])
    want = sim.predict_signal_dn(_slit_scenes(idx, n, m, 3), gains)
    got = np.stack([_slit_signal_dn(factors, gains, range(i, i + 1), n)[0] for i in idx])
    assert np.max(np.abs(got - want)) <= 1e-9 * np.max(np.abs(want))


def test_non_separable_physics_falls_back_to_the_simulator() -> None:
    d = load_profile("virtual-mini").contract_dict()
    d["physics"] = {"display_gamma": {"gamma": 2.2}}
    assert slit_factors(Simulator(Profile.model_validate(d)), 3) is None
