"""Discovers plugins from the ``thintact`` entry-point group and indexes what they provide.

A plugin that fails to import, whose hooks raise, or whose hooks return anything but an
iterable of :class:`~thintact_sdk.hookspecs.Component` is recorded with its error and
skipped (the valid components of a partly bad hook result are kept); the others still
load. ``thintact plugins`` prints the result. A component factory that raises anything but
a :class:`~thintact_sdk.errors.ThinTactError` raises :class:`PluginError` naming the plugin
and the component (the original exception is its ``__cause__``), recorded in
:attr:`PluginInfo.failures`.

Every component is reachable by its plain name (``virtual``) and by its namespaced name
``<plugin>:<name>`` (``virtual:virtual``, ``acme:virtual``). When two plugins provide a
component of the same kind and name, the plain name is ambiguous: asking for it raises a
:class:`PluginError` naming both packages, whatever order they loaded in, so a third-party
package can never silently take the place of the SDK's own component.
"""

from __future__ import annotations

import importlib
import importlib.metadata as md
import itertools
import traceback
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, overload

import pluggy

from thintact_sdk.errors import PluginError, ThinTactError
from thintact_sdk.hookspecs import KINDS, PROJECT, Component, ThinTactSpec
from thintact_sdk.interfaces import Camera, Decoder, Display, LightController, MaskDesigner

ENTRY_POINT_GROUP = "thintact"
BUILTIN_PLUGINS = {"thintact-sdk": "thintact_sdk.reconstruction.decoders.components"}
"""The core's own components (plugin name → module), registered through the same hooks as an
entry point and before them (:meth:`PluginRegistry.load_builtins`): the paper's decoders."""
MAX_COMPONENTS_PER_HOOK = 1000
"""A hook yielding more components than this is refused (an endless generator)."""
MAX_FAILURES = 20
"""Factory failures kept per plugin (the newest)."""

_HOOK_OF_KIND = {
    "camera": "thintact_cameras",
    "light_controller": "thintact_light_controllers",
    "mask": "thintact_masks",
    "decoder": "thintact_decoders",
    "display": "thintact_displays",
    "cli_command": "thintact_cli_commands",
    "benchmark": "thintact_benchmarks",
    "device_lister": "thintact_device_listers",
}


@dataclass
class PluginInfo:
    """A discovered plugin: where it came from, and what it provides or why it failed."""

    name: str
    module: str
    distribution: str | None
    version: str | None
    error: str | None = None
    provides: dict[str, list[str]] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    """Component factories of this plugin that raised a non-SDK exception (newest last)."""

    def fail(self, message: str) -> None:
        """Record a load failure (several are joined, the first stays first)."""
        self.error = message if not self.error else f"{self.error}; {message}"


class PluginRegistry:
    """All plugins found, and their components indexed by kind and name."""

    def __init__(self) -> None:
        self.pm = pluggy.PluginManager(PROJECT)
        self.pm.add_hookspecs(ThinTactSpec)
        self.plugins: dict[str, PluginInfo] = {}
        self._components: dict[str, dict[str, Component]] = {k: {} for k in KINDS}
        # kind -> plain name -> every plugin providing it, in load order (2+ = a collision)
        self._providers: dict[str, dict[str, list[str]]] = {k: {} for k in KINDS}
        # kind -> "plugin:name" -> component
        self._namespaced: dict[str, dict[str, Component]] = {k: {} for k in KINDS}

    # -- loading -----------------------------------------------------------------------
    def load_builtins(self) -> None:
        """Register the core's modules of :data:`BUILTIN_PLUGINS` as plugins (pluggy style),
        exactly as an entry point would be; a failure is recorded, not raised."""
        for name, module in BUILTIN_PLUGINS.items():
            if name in self.plugins:
                continue
            info = PluginInfo(name=name, module=module, distribution="thintact-sdk",
                              version=_sdk_version())
            self.plugins[name] = info
            try:
                obj = importlib.import_module(module)
            except Exception as err:  # noqa: BLE001 - reported like a plugin's import failure
                info.error = f"{type(err).__name__}: {err}"
                continue
            self.register(obj, name, info)

    def load_entry_points(self, group: str = ENTRY_POINT_GROUP) -> None:
        """Import every entry point in ``group``; failures are recorded, not raised."""
        for ep in sorted(md.entry_points(group=group), key=lambda e: e.name):
            if ep.name in self.plugins:
                continue
            dist = getattr(ep, "dist", None)
            info = PluginInfo(
                name=ep.name,
                module=ep.value,
                distribution=dist.metadata["Name"] if dist is not None else None,
                version=dist.version if dist is not None else None,
            )
            self.plugins[ep.name] = info
            try:
                obj = ep.load()
            except Exception as err:  # noqa: BLE001 - any import failure is reported
                info.error = f"{type(err).__name__}: {err}"
                info.traceback = traceback.format_exc()  # type: ignore[attr-defined]
                continue
            self.register(obj, ep.name, info)

    def register(self, obj: Any, name: str, info: PluginInfo | None = None) -> None:
        """Register an already-imported plugin object (module or instance)."""
        if info is None:
            info = PluginInfo(name=name, module=getattr(obj, "__name__", repr(obj)), distribution=None, version=None)
            self.plugins[name] = info
        try:
            self.pm.register(obj, name=name)
        except Exception as err:  # noqa: BLE001
            info.error = f"{type(err).__name__}: {err}"
            return
        for kind, hook_name in _HOOK_OF_KIND.items():
            impls = [i for i in getattr(self.pm.hook, hook_name).get_hookimpls() if i.plugin_name == name]
            for impl in impls:
                try:
                    result = impl.function()
                    comps = _components_of(result, hook_name, info)
                except Exception as err:  # noqa: BLE001 - a plugin's bug is recorded, not raised
                    info.fail(f"{hook_name} raised {type(err).__name__}: {err}")
                    continue
                for comp in comps:
                    comp.plugin = name
                    self._namespaced[kind][f"{name}:{comp.name}"] = comp
                    providers = self._providers[kind].setdefault(comp.name, [])
                    if name not in providers:
                        providers.append(name)
                    info.provides.setdefault(kind, []).append(comp.name)
                    if len(providers) > 1:
                        info.error = (
                            f"{kind} {comp.name!r} is also provided by "
                            f"{self._describe(providers[0])}; use '{name}:{comp.name}' or "
                            f"'{providers[0]}:{comp.name}' to choose"
                        )
                        continue
                    self._components[kind][comp.name] = comp

    # -- queries -----------------------------------------------------------------------
    def components(self, kind: str) -> dict[str, Component]:
        """All components of ``kind`` (one of :data:`thintact_sdk.hookspecs.KINDS`)."""
        if kind not in self._components:
            raise PluginError(f"unknown component kind {kind!r}; kinds: {', '.join(KINDS)}")
        return dict(self._components[kind])

    def with_trait(self, kind: str, trait: str) -> list[Component]:
        """Components of ``kind`` declaring ``trait`` (a word, or the key of ``key=value``),
        in load order: the core's built-ins first, then the entry points by name."""
        return [c for c in self.components(kind).values()
                if trait in c.traits or any(t.startswith(f"{trait}=") for t in c.traits)]

    def _describe(self, plugin: str) -> str:
        """``plugin 'acme' (package acme-thintact-camera 1.2.3)`` for error messages."""
        info = self.plugins.get(plugin)
        if info is None or info.distribution is None:
            return f"plugin {plugin!r}"
        return f"plugin {plugin!r} (package {info.distribution} {info.version or ''})".replace(" )", ")")

    def collisions(self, kind: str) -> dict[str, list[str]]:
        """Plain names of ``kind`` provided by two or more plugins → those plugins."""
        self.components(kind)  # validates kind
        return {n: list(p) for n, p in self._providers[kind].items() if len(p) > 1}

    def get(self, kind: str, name: str) -> Component:
        """The component ``name`` (or ``plugin:name``) of ``kind``.

        Raises
        ------
        PluginError
            Unknown name (the message lists the alternatives), or a plain name that two
            plugins provide (the message names both packages and the namespaced choices).
        """
        comps = self.components(kind)
        if ":" in name:
            if name in self._namespaced[kind]:
                return self._namespaced[kind][name]
        elif len(self._providers[kind].get(name, [])) > 1:
            who = self._providers[kind][name]
            raise PluginError(
                f"{kind.replace('_', ' ')} name {name!r} is provided by "
                f"{' and '.join(self._describe(p) for p in who)}; choose one explicitly in "
                f"the profile: {' or '.join(repr(f'{p}:{name}') for p in who)}"
            )
        elif name in comps:
            return comps[name]
        failed = [f"{p.name} ({p.error})" for p in self.plugins.values() if p.error]
        hint = f"; plugins that failed to load: {', '.join(failed)}" if failed else ""
        known = ", ".join(sorted(comps) + sorted(f"{p}:{n}" for n, ps in self.collisions(kind).items()
                                                 for p in ps)) or "(none installed)"
        raise PluginError(f"no {kind.replace('_', ' ')} plugin named {name!r}; available: {known}{hint}")

    @overload
    def create(self, kind: Literal["camera"], name: str, *args: Any, **kwargs: Any) -> Camera: ...
    @overload
    def create(self, kind: Literal["decoder"], name: str, *args: Any, **kwargs: Any) -> Decoder: ...
    @overload
    def create(self, kind: Literal["display"], name: str, *args: Any, **kwargs: Any) -> Display: ...
    @overload
    def create(self, kind: Literal["light_controller"], name: str, *args: Any,
               **kwargs: Any) -> LightController: ...
    @overload
    def create(self, kind: Literal["mask"], name: str, *args: Any, **kwargs: Any) -> MaskDesigner: ...
    @overload
    def create(self, kind: str, name: str, *args: Any, **kwargs: Any) -> Any: ...

    def create(self, kind: str, name: str, *args: Any, **kwargs: Any) -> Any:
        """Build component ``name`` of ``kind`` with its factory (signatures per kind:
        :mod:`thintact_sdk.hookspecs`); typed by kind for the kinds with an interface.

        Raises
        ------
        ThinTactError
            What the factory raised when it is an SDK error (bad settings, missing device).
        PluginError
            The name is unknown or ambiguous (:meth:`get`), or the factory raised any other
            exception: the message names the plugin and the component, the original is the
            ``__cause__``, and the failure is kept in the plugin's :attr:`PluginInfo.failures`.
        """
        comp = self.get(kind, name)
        try:
            return comp.factory(*args, **kwargs)
        except ThinTactError:
            raise
        except Exception as err:
            what = f"{kind.replace('_', ' ')} {comp.name!r} of {self._describe(comp.plugin)}"
            message = f"{what} failed to build: {type(err).__name__}: {err}"
            info = self.plugins.get(comp.plugin)
            if info is not None:
                info.failures = [*info.failures, message][-MAX_FAILURES:]
            raise PluginError(message) from err


def _components_of(result: object, hook_name: str, info: PluginInfo) -> list[Component]:
    """The valid components of a hook's ``result``; each invalid entry is recorded on ``info``.

    Raises
    ------
    PluginError
        ``result`` is not an iterable of components at all (a number, text, a mapping), or
        yields more than :data:`MAX_COMPONENTS_PER_HOOK` entries.
    """
    if result is None:
        return []
    if isinstance(result, str | bytes | Mapping) or not isinstance(result, Iterable):
        raise PluginError(f"returned {type(result).__name__} {_short(result)}, not a list of Component")
    entries = list(itertools.islice(result, MAX_COMPONENTS_PER_HOOK + 1))
    if len(entries) > MAX_COMPONENTS_PER_HOOK:
        raise PluginError(f"returned more than {MAX_COMPONENTS_PER_HOOK} components")
    good: list[Component] = []
    for k, entry in enumerate(entries):
        if not isinstance(entry, Component):
            info.fail(f"{hook_name} entry {k} is {type(entry).__name__} {_short(entry)}, not a Component")
        elif not isinstance(entry.name, str) or not entry.name or ":" in entry.name:
            info.fail(f"{hook_name} entry {k} has an invalid name {_short(entry.name)} "
                      "(non-empty text without ':')")
        elif not callable(entry.factory):
            info.fail(f"{hook_name} component {entry.name!r} has a factory that is not callable")
        else:
            good.append(entry)
    return good


def _sdk_version() -> str | None:
    try:
        return md.version("thintact-sdk")
    except md.PackageNotFoundError:
        return None


def _short(value: object) -> str:
    """``repr(value)``, at most 60 characters (a plugin's repr may be long or fail)."""
    try:
        text = repr(value)
    except Exception:  # noqa: BLE001 - a broken __repr__ must not hide the real problem
        text = f"<{type(value).__name__}>"
    return text if len(text) <= 60 else text[:57] + "..."


_REGISTRY: PluginRegistry | None = None


def get_registry(reload: bool = False) -> PluginRegistry:
    """The process-wide registry, loading entry points on first use."""
    global _REGISTRY
    if _REGISTRY is None or reload:
        reg = PluginRegistry()
        reg.load_builtins()
        reg.load_entry_points()
        _REGISTRY = reg
    return _REGISTRY
