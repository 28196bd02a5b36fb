"""Each effect is declared in one place: its stage, parameters and bounds, application, words
and fit hints are consistent, and the simulator and the diagnosis read them from there."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.diagnosis.imaging.candidates import CANDIDATES
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.simulation.effects import (
    EFFECTS,
    STAGES,
    EffectSpec,
    ParamSpec,
    register_effect,
    resolve_physics,
    unregister_effect,
)
from thintact_sdk.simulation.simulator import kernel_params


@pytest.fixture(scope="module")
def mini():  # noqa: ANN201
    return load_profile("virtual-mini").with_physics({})


@pytest.mark.parametrize("name", list(EFFECTS))
def test_declaration_is_complete_and_consistent(name: str, mini) -> None:  # noqa: ANN001
    spec = EFFECTS[name]
    assert spec.stage in STAGES
    assert (spec.kernel is not None) == (spec.stage == "kernel")
    assert (spec.forward is not None) == (spec.stage != "kernel")
    assert spec.describe is not None, "every CONTRACTS §5 effect says what it is in words"
    assert set(spec.distinguish) <= set(EFFECTS)
    fit = spec.fit
    assert fit is not None
    lo, hi = spec.fit_bounds(mini)
    for vec in (fit.null(mini), fit.step(mini), lo, hi):
        assert np.shape(vec) == (fit.k,)
    assert np.all(lo < hi)
    assert len(fit.signed) in (0, fit.k)
    if fit.domain == "dn":
        assert fit.dn_response is not None
    if fit.domain == "linear":
        assert fit.basis is not None and fit.report is not None
    defaults = resolve_physics({name: {}})[name]
    assert spec.describe(fit.to_params(fit.step(mini) + fit.null(mini), mini), mini)
    if fit.bounds is None:  # the diagnosis searches the effect's own physical range
        np.testing.assert_array_equal(CANDIDATES[name].upper(mini), spec.param_bounds()[1])
    assert defaults.keys() == spec.params.keys()


def test_sensor_blur_has_one_bound_for_profiles_and_diagnosis(mini) -> None:  # noqa: ANN001
    assert EFFECTS["sensor_blur"].params["sigma_um"].bounds == (0.0, 500.0)
    assert CANDIDATES["sensor_blur"].upper(mini)[0] == 500.0


def test_kernel_stage_effect_reaches_the_kernel_through_its_declaration(mini) -> None:  # noqa: ANN001
    toy = EffectSpec(
        name="toy_leaky_cells", stage="kernel", description="test-only: closed cells leak",
        params={"t": ParamSpec("1", 0.0, (0.0, 1.0))},
        kernel=lambda params, _p: {"leakage": params["t"]},
    )
    register_effect(toy)
    try:
        phys = resolve_physics({"toy_leaky_cells": {"t": 0.25}})
        assert kernel_params(mini, phys).leakage == 0.25
    finally:
        unregister_effect("toy_leaky_cells")
    assert kernel_params(mini, resolve_physics({})).leakage == 0.0


def test_physics_imports_no_higher_layer() -> None:
    """``formats.profiles`` validates the effects and the simulator/diagnosis apply them: the
    effects import none of them (it reads profiles through the structural ``DeviceProfile``)."""
    import ast
    from pathlib import Path

    import thintact_sdk.simulation.effects as physics

    for path in Path(physics.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            mods = [node.module or ""] if isinstance(node, ast.ImportFrom) else \
                [a.name for a in node.names] if isinstance(node, ast.Import) else []
            for m in mods:
                outside = m.startswith("thintact_sdk.simulation.") and \
                    not m.startswith("thintact_sdk.simulation.effects")
                assert not outside and not m.startswith((
                    "thintact_sdk.formats.profiles", "thintact_sdk.reconstruction",
                    "thintact_sdk.diagnosis")), f"{path.name} imports {m}"
