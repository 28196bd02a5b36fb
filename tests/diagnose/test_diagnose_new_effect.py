"""Adding a physical effect is one declaration: a toy effect written and registered in this
file only is applied by the simulator (through its declared stage) and named and fitted by
``diagnose`` on a recording that hides it, with nothing else changed in the SDK."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from thintact_sdk.diagnosis.imaging import DiagnoseOptions, DiagnosisData, diagnose
from thintact_sdk.formats.profiles import Profile, load_profile
from thintact_sdk.simulation.effects import (
    EFFECTS,
    EffectSpec,
    ParamSpec,
    PhysicsError,
    register_effect,
    unregister_effect,
)
from thintact_sdk.simulation.effects._spec import scalar_fit
from thintact_sdk.simulation.noise import signal_to_dn
from thintact_sdk.simulation.simulator import Simulator

NAME = "responsivity_tilt"


def _tilt(signal: np.ndarray, params: Any, _profile: Profile) -> np.ndarray:
    """``F × R × S × C`` signal times ``1 + slope·y``, y from −1 (first row) to +1 (last)."""
    y = np.linspace(-1.0, 1.0, signal.shape[1])[None, :, None, None]
    return signal * (1.0 + float(params["slope"]) * y)


TILT = EffectSpec(
    name=NAME,
    stage="signal",
    order=30,
    description="the pixels' responsivity changes linearly from the first to the last row",
    params={"slope": ParamSpec("1", 0.0, (-0.5, 0.5), "relative change, centre to last row")},
    forward=_tilt,
    describe=lambda params, _p: (
        f"The responsivity tilts by {float(params['slope']):+.2%} from the centre to the last row."
    ),
    fit=scalar_fit("slope", 0.0, 0.02, signed=True, domain="post"),
)


@pytest.fixture
def tilt() -> Iterator[EffectSpec]:
    spec = register_effect(TILT)
    try:
        yield spec
    finally:
        unregister_effect(NAME)


def _profile() -> Profile:
    return load_profile("virtual-mini").with_physics({})


def test_unregistered_effect_is_refused_and_registration_is_one_place() -> None:
    prof = _profile().with_physics({NAME: {"slope": 0.02}})
    with pytest.raises(PhysicsError, match="unknown effect"):
        Simulator(prof)
    register_effect(TILT)
    try:
        with pytest.raises(PhysicsError, match="already registered"):
            register_effect(TILT)
        assert EFFECTS[NAME] is TILT
    finally:
        unregister_effect(NAME)
    assert NAME not in EFFECTS
    with pytest.raises(PhysicsError, match="CONTRACTS"):
        unregister_effect("sensor_blur")


def test_simulator_applies_the_registered_effect_in_its_stage(tilt: EffectSpec) -> None:
    prof = _profile()
    rng = np.random.default_rng(1)
    scenes = rng.random((2, prof.scene.rows, prof.scene.cols, 3))
    base = Simulator(prof).forward_batch(scenes)
    tilted = Simulator(prof.with_physics({NAME: {"slope": 0.05}})).forward_batch(scenes)
    y = np.linspace(-1.0, 1.0, prof.sensor.rows)[None, :, None, None]
    np.testing.assert_allclose(tilted, base * (1.0 + 0.05 * y), rtol=1e-12)
    # its stage order: after the other signal effects (veiling glare sees the untilted signal)
    both = {"veiling_glare": {"fraction": 0.1}, NAME: {"slope": 0.05}}
    glare = Simulator(prof.with_physics({"veiling_glare": {"fraction": 0.1}})).forward_batch(scenes)
    np.testing.assert_allclose(Simulator(prof.with_physics(both)).forward_batch(scenes),
                               glare * (1.0 + 0.05 * y), rtol=1e-12)


def _hidden_tilt_recording(slope: float, seed: int = 3) -> DiagnosisData:
    """8 frames of virtual-mini rendered with the tilt and the sensor noise; the profile
    the diagnosis gets has no physics."""
    prof = _profile()
    rng = np.random.default_rng(seed)
    n, m = prof.scene.rows, prof.scene.cols
    yy, xx = np.mgrid[0:n, 0:m]
    scenes = np.concatenate([
        np.ones((1, n, m, 3)),
        np.broadcast_to((((yy // 6) + (xx // 6)) % 2)[None, :, :, None], (1, n, m, 3)),
        rng.random((6, n, m, 3)),
    ]).astype(float)
    sim = Simulator(prof.with_physics({NAME: {"slope": slope}}))
    signal = sim.predict_signal_dn(scenes, Simulator(prof).reference_gain())
    meas = np.stack([np.round(signal_to_dn(s, prof.noise, rng)) for s in signal])
    return DiagnosisData(prof, [f"frame{i}" for i in range(len(scenes))], scenes, meas)


def test_diagnose_names_and_fits_the_hidden_registered_effect(tilt: EffectSpec) -> None:
    data = _hidden_tilt_recording(slope=0.02)
    d = diagnose(data, options=DiagnoseOptions(time_budget_s=60.0))
    rep = d.report
    assert [f["effect"] for f in rep["findings"]] == [NAME]
    assert rep["findings"][0]["params"]["slope"] == pytest.approx(0.02, abs=0.002)
    assert "tilts by +2" in rep["findings"][0]["evidence"]
    assert rep["baseline"]["chi2_per_dof"] > 1.1
    assert rep["final"]["chi2_per_dof"] == pytest.approx(1.0, abs=0.05)
    assert d.fitted_profile.physics[NAME]["slope"] == pytest.approx(0.02, abs=0.002)

