"""The plugin registry against hostile plugins (issue 30): hooks returning something other
than Components, and factories raising arbitrary exceptions, are recorded per plugin and
surface as PluginError naming plugin and component, never unwrapped. In-process fakes."""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thintact_sdk import Component, hookimpl
from thintact_sdk.device.registry import MAX_COMPONENTS_PER_HOOK, PluginRegistry
from thintact_sdk.errors import CameraSettingsError, PluginError


def _plugin(label: str, cameras: Callable[[], Any]) -> types.ModuleType:
    mod = types.ModuleType(f"fake_{label}")

    @hookimpl
    def thintact_cameras() -> Any:
        return cameras()

    mod.thintact_cameras = thintact_cameras  # type: ignore[attr-defined]
    return mod


def _good(label: str = "good") -> types.ModuleType:
    return _plugin(label, lambda: [Component(f"{label}-cam", lambda *a: f"{label} camera")])


def _registry(**plugins: types.ModuleType) -> PluginRegistry:
    reg = PluginRegistry()
    for name, mod in plugins.items():
        reg.register(mod, name)
    return reg


@pytest.mark.parametrize(("result", "why"), [
    (42, "returned int 42, not a list of Component"),
    ("acme-cam", "returned str 'acme-cam'"),
    ({"name": "x"}, "returned dict"),
    (3.5, "returned float"),
    (object(), "returned object"),
])
def test_hook_returning_a_non_list_is_recorded(result, why):
    reg = _registry(bad=_plugin("bad", lambda: result), good=_good())
    assert "thintact_cameras raised PluginError" in reg.plugins["bad"].error and why in reg.plugins["bad"].error
    assert reg.plugins["bad"].provides == {}
    assert reg.create("camera", "good-cam") == "good camera"
    assert reg.plugins["good"].error is None


def test_list_with_non_components_keeps_the_valid_ones():
    comp = Component("ok-cam", lambda *a: "ok")
    reg = _registry(mixed=_plugin("mixed", lambda: [1, "x", None, comp, Component("", lambda: 0),
                                                    Component("a:b", lambda: 0),
                                                    Component("nf", 5)]))  # type: ignore[arg-type]
    err = reg.plugins["mixed"].error
    for part in ("entry 0 is int 1", "entry 1 is str 'x'", "entry 2 is NoneType None",
                 "entry 4 has an invalid name ''", "entry 5 has an invalid name 'a:b'",
                 "'nf' has a factory that is not callable"):
        assert part in err, err
    assert reg.plugins["mixed"].provides == {"camera": ["ok-cam"]}
    assert reg.create("camera", "ok-cam") == "ok"
    with pytest.raises(PluginError, match="no camera plugin named 'nf'"):
        reg.get("camera", "nf")


def test_generators_work_and_endless_ones_are_refused():
    def endless():
        while True:
            yield Component("dup", lambda: 0)

    reg = _registry(gen=_plugin("gen", lambda: (Component(n, lambda n=n: n) for n in ("g1", "g2"))),
                    endless=_plugin("endless", endless),
                    failing=_plugin("failing", lambda: (1 / 0 for _ in range(3))))
    assert reg.plugins["gen"].provides == {"camera": ["g1", "g2"]} and reg.plugins["gen"].error is None
    assert f"more than {MAX_COMPONENTS_PER_HOOK}" in reg.plugins["endless"].error
    assert "ZeroDivisionError" in reg.plugins["failing"].error
    assert not reg.plugins["endless"].provides and not reg.plugins["failing"].provides


def test_factory_raising_is_a_plugin_error_naming_plugin_and_component():
    def boom(*args: Any) -> Any:
        return 1 / 0

    reg = _registry(acme=_plugin("acme", lambda: [Component("acme-cam", boom)]))
    with pytest.raises(PluginError, match=r"camera 'acme-cam' of plugin 'acme' failed to build: "
                                          r"ZeroDivisionError") as err:
        reg.create("camera", "acme-cam", None, {})
    assert isinstance(err.value.__cause__, ZeroDivisionError)
    with pytest.raises(PluginError):
        reg.create("camera", "acme:acme-cam")
    assert len(reg.plugins["acme"].failures) == 2 and "ZeroDivisionError" in reg.plugins["acme"].failures[0]
    assert reg.plugins["acme"].error is None  # it loaded; building failed


def test_sdk_errors_from_a_factory_pass_through_unchanged():
    def picky(*args: Any) -> Any:
        raise CameraSettingsError("camera.settings.fps: bad")

    reg = _registry(acme=_plugin("acme", lambda: [Component("acme-cam", picky)]))
    with pytest.raises(CameraSettingsError, match="camera.settings.fps"):
        reg.create("camera", "acme-cam")
    assert reg.plugins["acme"].failures == []


def test_a_hook_that_raises_base_exception_subclasses_is_not_swallowed():
    reg = PluginRegistry()
    with pytest.raises(KeyboardInterrupt):
        reg.register(_plugin("ki", lambda: (_ for _ in ()).throw(KeyboardInterrupt)), "ki")


hostile = st.recursive(
    st.one_of(st.none(), st.integers(), st.floats(), st.text(max_size=5), st.booleans(),
              st.builds(lambda n: Component(n, lambda *a: n), st.text(max_size=6))),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.tuples(inner, inner),
                            st.dictionaries(st.text(max_size=3), inner, max_size=2)),
    max_leaves=8,
)


@settings(max_examples=50, deadline=None)
@given(result=hostile)
def test_fuzzed_hook_results_never_escape_the_registry(result):
    reg = _registry(fuzz=_plugin("fuzz", lambda: result), good=_good())
    info = reg.plugins["fuzz"]
    for name in info.provides.get("camera", []):
        comp = reg.get("camera", f"fuzz:{name}")
        assert isinstance(comp, Component) and comp.plugin == "fuzz"
    assert reg.create("camera", "good-cam") == "good camera"
    if info.error is None:
        assert result is None or isinstance(result, list | tuple)


def _command_plugin(factory: Callable[..., Any]) -> types.ModuleType:
    mod = types.ModuleType("fake_cli_plugin")

    @hookimpl
    def thintact_cli_commands() -> Any:
        return [Component("boom", factory)]

    @hookimpl
    def thintact_benchmarks() -> Any:
        return [Component("boom-bench", factory)]

    mod.thintact_cli_commands = thintact_cli_commands  # type: ignore[attr-defined]
    mod.thintact_benchmarks = thintact_benchmarks  # type: ignore[attr-defined]
    return mod


def test_a_cli_command_plugin_whose_factory_raises_leaves_every_command_working(monkeypatch, capfd):
    """The CLI builds plugin commands through the registry: a factory raising ZeroDivisionError
    is recorded on its plugin, the other commands still run, and the broken benchmark is one
    clean error when asked for."""
    import thintact_sdk.device.registry as pm
    from thintact_sdk.apps.cli.main import main

    monkeypatch.setattr(pm, "_REGISTRY", None)  # a registry of this test's own, restored after
    reg = pm.get_registry()
    reg.register(_command_plugin(lambda *a: 1 / 0), "fake-cli")
    capfd.readouterr()
    assert main(["profile", "list"]) == 0
    assert any("ZeroDivisionError" in f for f in reg.plugins["fake-cli"].failures)
    assert main(["bench", "boom-bench"]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "boom-bench" in err[0] and "Traceback" not in err[0]
